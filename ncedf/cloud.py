"""A surface model of a sparse obstacle cloud: extra points between near neighbours.

A cloud sampled uniformly on obstacle surfaces at a few points per square metre
has holes wider than the robot: at the paper's 4 points per m^2 on the
cluttered scene's box faces, 31% of the surface is more than 0.3 m from the
nearest sample and holes reach 0.7-0.8 m, so a link of radius 0.2 m slides into
a box face while every observed point is farther than the safety margin.
Points closer than ``max_edge`` are taken to lie on one surface, and the surface
between them is sampled:

* each point's tangent plane is that of its ``NORMAL_NEIGHBOURS`` nearest
  points (principal axes); around it, ``SECTORS`` equal angular sectors, and in
  each the nearest point at most ``max_edge`` away (an approximation of the
  point's Delaunay neighbours that does not leave one side unconnected, as the
  k nearest neighbours of a point on a hole's rim do);
* on each such edge, the points at ``EDGE_FRACTIONS`` of its length;
* in each triangle of the point and the neighbours of two adjacent sectors
  whose third edge is at most ``max_edge`` too, the points at
  ``TRIANGLE_WEIGHTS`` (barycentric);
* in each *empty* sector of a point that has neighbours in at least
  ``SURFACE_SECTORS`` others (a point on a hole's rim, or at the edge of a
  surface): the points ``EXTRAPOLATION * max_edge`` away along the sector's
  middle direction in the tangent plane. A hole too wide for the edges
  (radius up to ``max_edge / 2``) is covered from its rim; a surface's true
  edge grows by ``max_edge / 2`` in its own plane, like a margin. Isolated
  points (sphere centres) get nothing.

Measured on the cluttered scene's clouds (seeds 0-2, 400 test points per m^2 of
box face): with ``max_edge`` 1.2 m the share of the surface farther than 0.3 m
from the cloud falls from 29-31% to 2-3% (4% without the extrapolation), and
farther than 0.2 m from 59% to 8-10%; the largest hole, 0.71-0.81 m from the
nearest raw point, is 0.47-0.61 m from the nearest fill point. What is left is
not told apart from a passage by any local rule.

Two points of *different* obstacles closer than ``max_edge`` get joined too: a
gap narrower than ``max_edge`` is treated as closed (a tube of radius r with
margin d cannot pass between two points closer than ``2 (r + d)`` in any case).
Edges across a convex obstacle's corner run inside it.

Fill points are combinations of three observed points plus an offset:
``parents`` (F, 3) indices, ``weights`` (F, 3) and ``offsets`` (F, 3) (zero
but for extrapolated points), so anything defined per observed point (its
velocity, for an obstacle that translates) is carried over with
:func:`interpolate`. Fixed sizes: F = :func:`fill_count` (P) for P points
(padding included); unused slots are masked.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from ncedf.precision import MATMUL

#: Angular sectors around a point in which its neighbours are chosen.
SECTORS = 6
#: Nearest points whose principal axes give a point's tangent plane.
NORMAL_NEIGHBOURS = 8
#: Positions along an edge of its fill points (fractions of the edge from its first point).
EDGE_FRACTIONS = (1.0 / 3.0, 2.0 / 3.0)
#: Barycentric weights of the fill points inside a triangle (the point, its two neighbours).
TRIANGLE_WEIGHTS = ((1.0 / 3.0, 1.0 / 3.0, 1.0 / 3.0), (0.5, 0.25, 0.25), (0.25, 0.5, 0.25), (0.25, 0.25, 0.5))
#: Distances of the points extrapolated into an empty sector, in units of ``max_edge``.
EXTRAPOLATION = (0.25, 0.5)
#: Sectors with a neighbour that make a point part of a surface (extrapolated from).
SURFACE_SECTORS = 2


def fill_count(n_points: int) -> int:
    """Fill slots F for a cloud of ``n_points`` rows."""
    return n_points * SECTORS * (len(EDGE_FRACTIONS) + len(TRIANGLE_WEIGHTS) + len(EXTRAPOLATION))


def tangent_axes(points: jnp.ndarray, sq: jnp.ndarray):
    """Two tangent directions (P, 3) each: the principal axes of largest spread of each
    point's ``NORMAL_NEIGHBOURS`` nearest points (``sq``: (P, P) squared distances, inf
    for pairs to leave out)."""
    k = min(NORMAL_NEIGHBOURS, points.shape[0] - 1)
    neg, nbr = jax.lax.top_k(-sq, k)
    local = jnp.where(jnp.isfinite(neg)[..., None], points[nbr] - points[:, None], 0.0)  # (P, k, 3)
    _, vectors = jnp.linalg.eigh(jnp.einsum("pki,pkj->pij", local, local, precision=MATMUL))  # ascending eigenvalues
    return vectors[..., 2], vectors[..., 1]


def fill_weights(points: jnp.ndarray, mask: jnp.ndarray, max_edge: float):
    """The fill points of the surface model as combinations of observed points.

    Args:
      points: (P, 3) m.  mask: (P,) bool, True = real point.
      max_edge: longest edge taken to lie on a surface, m.
    Returns:
      parents (F, 3) int32 row indices, weights (F, 3) (rows sum to 1), offsets (F, 3) m,
      valid (F,) bool; fill point f is ``sum_i weights[f, i] points[parents[f, i]] + offsets[f]``;
      F = :func:`fill_count` (P).
    """
    n = points.shape[0]
    diff = points[None, :, :] - points[:, None, :]  # (P, P, 3): row i, column j holds p_j - p_i
    real = mask[:, None] & mask[None, :] & ~jnp.eye(n, dtype=bool)
    sq = jnp.where(real, jnp.sum(diff * diff, axis=-1), jnp.inf)
    e1, e2 = tangent_axes(points, sq)
    angle = jnp.arctan2(jnp.einsum("ijc,ic->ij", diff, e2, precision=MATMUL),
                        jnp.einsum("ijc,ic->ij", diff, e1, precision=MATMUL))
    sector = jnp.floor((angle + jnp.pi) * (SECTORS / (2.0 * jnp.pi))).astype(jnp.int32) % SECTORS
    near = sq <= max_edge * max_edge
    in_sector = near[..., None] & (sector[..., None] == jnp.arange(SECTORS))  # (P, P, S)
    masked = jnp.where(in_sector, sq[..., None], jnp.inf)
    nbr = jnp.argmin(masked, axis=1).astype(jnp.int32)  # (P, S)
    has = jnp.isfinite(jnp.min(masked, axis=1))  # (P, S)

    own = jnp.broadcast_to(jnp.arange(n, dtype=jnp.int32)[:, None], (n, SECTORS))
    nxt = jnp.roll(nbr, -1, axis=1)
    tri_ok = has & jnp.roll(has, -1, axis=1) & (sq[nbr, nxt] <= max_edge * max_edge)
    tri_ok = tri_ok & (nbr != nxt)

    middle = -np.pi + (np.arange(SECTORS) + 0.5) * (2.0 * np.pi / SECTORS)  # (S,)
    direction = (np.cos(middle)[None, :, None] * e1[:, None, :]
                 + np.sin(middle)[None, :, None] * e2[:, None, :])  # (P, S, 3)
    reach = max_edge * jnp.asarray(EXTRAPOLATION, points.dtype)  # (X,)
    rim = ~has & (jnp.sum(has, axis=1, keepdims=True) >= SURFACE_SECTORS)  # (P, S)

    edge_w = np.array([[1.0 - t, t, 0.0] for t in EDGE_FRACTIONS], np.float32)  # (E, 3)
    tri_w = np.array(TRIANGLE_WEIGHTS, np.float32)  # (T, 3)
    out_w = np.tile(np.array([[1.0, 0.0, 0.0]], np.float32), (len(EXTRAPOLATION), 1))  # (X, 3)
    e, t, x = len(edge_w), len(tri_w), len(out_w)
    parents = jnp.concatenate([
        jnp.broadcast_to(jnp.stack([own, nbr, own], axis=-1)[:, :, None], (n, SECTORS, e, 3)),
        jnp.broadcast_to(jnp.stack([own, nbr, nxt], axis=-1)[:, :, None], (n, SECTORS, t, 3)),
        jnp.broadcast_to(jnp.stack([own, own, own], axis=-1)[:, :, None], (n, SECTORS, x, 3)),
    ], axis=2).reshape(-1, 3)
    weights = jnp.broadcast_to(jnp.asarray(np.concatenate([edge_w, tri_w, out_w]), points.dtype),
                               (n, SECTORS, e + t + x, 3)).reshape(-1, 3)
    offsets = jnp.concatenate([jnp.zeros((n, SECTORS, e + t, 3), points.dtype),
                               direction[:, :, None, :] * reach[None, None, :, None]], axis=2).reshape(-1, 3)
    valid = jnp.concatenate([jnp.broadcast_to(has[..., None], (n, SECTORS, e)),
                             jnp.broadcast_to(tri_ok[..., None], (n, SECTORS, t)),
                             jnp.broadcast_to(rim[..., None], (n, SECTORS, x))], axis=2).reshape(-1)
    return parents, weights, offsets, valid


def interpolate(values: jnp.ndarray, parents: jnp.ndarray, weights: jnp.ndarray) -> jnp.ndarray:
    """(F, C): ``sum_i weights[f, i] values[parents[f, i]]`` for per-point values (P, C)."""
    return jnp.einsum("fi,fic->fc", weights, values[parents], precision=MATMUL)


def fill_surface(points: jnp.ndarray, mask: jnp.ndarray, max_edge: float):
    """The cloud with its fill points appended: points (P + F, 3) m and mask (P + F,) bool."""
    parents, weights, offsets, valid = fill_weights(points, mask, max_edge)
    return (jnp.concatenate([points, interpolate(points, parents, weights) + offsets]),
            jnp.concatenate([mask, valid]))
