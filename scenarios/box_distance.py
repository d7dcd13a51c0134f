"""The exact signed distance between the robot and an axis-aligned box, with a certificate.

R is the robot body of :mod:`ncedf.geometry`, S its lateral surfaces with the base and tip
disks (:mod:`scenarios.robot_cells`), ``phi`` the closed-form box SDF. The truth is
``d(R, B) = min(min_{x in S} phi(x), sdf_R(centre of B))``: S lies in R and holds the boundary
of R, so when R and B are disjoint the closest point of R is on S (the second term is then >= the
first); ``d < 0`` iff they overlap (a box inside the robot without touching S is caught by the
centre term).

``min_S phi`` is a branch and bound over cells of the surface coordinates (u, psi, w). A cell with
centre x0 = p(xi0) and half extents (dA, dB) gets the value ``phi(x0)`` (x0 is in R: an upper bound)
and, for all its points, the lower bound ``max(phi(x0) + min over the cell of g.(p - x0), phi(x0) -
S_A dA - S_B dB)``: the first because phi is convex (``phi(y) >= phi(x0) + g.(y - x0)``, g a unit
subgradient), the second because phi is 1-Lipschitz and every point of the cell is reached from x0
along coordinate lines by a path of length <= ``S_A dA + S_B dB`` (lateral ``|p_u| <= L + theta
r``, ``|p_psi| = r``; disk ``|p_w| = r``, ``|p_psi| = w r``; theta the link's bend). The linear
minimum: on a lateral cell, at u0 the ring ``c + r e(psi)`` makes ``g.p`` a sinusoid in psi,
minimised exactly over the interval; moving along u at a fixed psi changes ``g.p`` by at most
``|g.t| (L + theta r) dA + theta (L + theta r) dA^2 / 2`` (``p_u = L (1 + kappa r cos psi) t`` is
parallel to the backbone tangent t, ``|p_uu| <= theta (L + theta r)``, kappa = theta / L). On a
(flat) disk cell ``g.p`` is w times a sinusoid in psi: its minimum over the annular sector is exact.
The coarse cells are all evaluated; the ``_KEEP`` cells with the lowest bounds are split, level
after level; the certificate is ``best value - min(bounds of all unsplit cells)``. Where it exceeds
``CERTIFIED`` (rare: deep penetrations, whose deepest points lie on ridges of the box SDF) the host
refines every cell whose bound is below ``best - CERTIFIED`` until none is left
(:func:`exhaustive_box`) -- unless the value is already below ``-CERTIFIED``: the penetration is
then certain and the value, the SDF at a real robot point, is kept (it may understate the depth,
never overstate it).
"""

from __future__ import annotations

import functools
from typing import Callable

import jax
import jax.numpy as jnp
import numpy as np

from ncedf.geometry import link_surface_points, robot_signed_distance
from ncedf.robot import RobotSpec, frame_to_world
from scenarios.robot_cells import coarse_robot_cells, robot_pose

# What the branch and bound certifies (m).
CERTIFIED = 0.004
# Each level splits the _KEEP lowest-bound cells into _SPLIT x _SPLIT children.
_SPLIT = 3
_BOX_LEVELS = 3
_KEEP = 32
_FALLBACK_CHUNK = 4096


def box_sdf(points: jnp.ndarray, centre: jnp.ndarray, half: jnp.ndarray):
    """Signed distance to an axis-aligned box and a unit subgradient.

    Args:
      points: (..., 3) m.  centre, half: (3,) centre and half edge lengths, m.
    Returns:
      sdf (...,) m (negative inside) and g (..., 3) with |g| = 1 and
      ``sdf(y) >= sdf(x) + g . (y - x)`` for all y (the sdf is convex).
    """
    rel = points - centre
    sign = jnp.where(rel >= 0.0, 1.0, -1.0)
    d = jnp.abs(rel) - half
    out = jnp.maximum(d, 0.0)
    out_sq = jnp.sum(out * out, axis=-1)
    outside = out_sq > 0.0
    out_norm = jnp.sqrt(jnp.where(outside, out_sq, 1.0))
    deepest = jnp.max(d, axis=-1)
    sdf = jnp.where(outside, out_norm, deepest)
    face = jax.nn.one_hot(jnp.argmax(d, axis=-1), 3, dtype=points.dtype)
    g = sign * jnp.where(outside[..., None], out / out_norm[..., None], face)
    return sdf, g


def cell_geometry(cells: dict, pose: dict, spec: RobotSpec) -> dict:
    """World points and coordinate tangents of surface cells.

    Returns arrays over cells: point (C, 3); tan_a (C, 3) the derivative of the surface map
    along u (lateral) or w (disks); tan_b along psi; tan_w along w (= r e, e the unit radial
    direction of the cross-section); theta (C,) the bend of the cell's link.
    """
    link, disk = cells["link"], cells["disk"]
    theta, phi, frames = pose["theta"][link], pose["phi"][link], pose["frames"][link]

    def world(coords):
        return frame_to_world(frames, link_surface_points(coords, theta, phi, spec, spec.radius_of(link)))

    point, push = jax.linearize(world, cells["coords"])
    unit = jnp.eye(3, dtype=point.dtype)
    tan_w = push(jnp.broadcast_to(unit[2], point.shape))
    return {
        "point": point,
        "tan_a": jnp.where(disk[:, None], tan_w, push(jnp.broadcast_to(unit[0], point.shape))),
        "tan_b": push(jnp.broadcast_to(unit[1], point.shape)),
        "tan_w": tan_w,
        "theta": theta,
    }


def _sinusoid_min(k0: jnp.ndarray, k1: jnp.ndarray, half: jnp.ndarray):
    """``min over |d| <= half of k0 cos d + k1 sin d`` (half < pi) and its argmin d, elementwise."""
    amplitude = jnp.sqrt(k0 * k0 + k1 * k1)
    trough = jnp.arctan2(k1, k0) - jnp.pi  # in [-2 pi, 0]
    trough = jnp.where(trough < -jnp.pi, trough + 2.0 * jnp.pi, trough)
    low = k0 * jnp.cos(half) - k1 * jnp.sin(half)
    high = k0 * jnp.cos(half) + k1 * jnp.sin(half)
    inside = jnp.abs(trough) <= half
    value = jnp.where(inside, -amplitude, jnp.minimum(low, high))
    arg = jnp.where(inside, trough, jnp.where(low <= high, -half, half))
    return value, arg


def _cell_bounds(geometry: dict, cells: dict, sdf: Callable, spec: RobotSpec):
    """Value (C,) and lower bound (C,) over each surface cell of ``min_k f_k``, each f_k convex
    and 1-Lipschitz (module docstring), and the surface coordinates (C, 3) where the lowest
    linearisation is lowest.

    ``sdf(points (C, 3)) -> (values (C, K), subgradients (C, K, 3) of norm <= 1)``.
    """
    value, g = sdf(geometry["point"])
    coords, half, disk = cells["coords"][:, None], cells["half"][:, None], cells["disk"][:, None]
    da, db = half[..., 0], half[..., 1]
    length, r = spec.length, spec.radius_of(cells["link"][:, None])
    theta = geometry["theta"][:, None]
    tan_a, tan_b, tan_w = (geometry[k][:, None] for k in ("tan_a", "tan_b", "tan_w"))
    slope_a = jnp.sum(g * tan_a, axis=-1)
    w0 = coords[..., 2]
    # g . r e(psi0 + d) = k0 cos d + k1 sin d (e the unit radial direction of the cross-section)
    k0 = jnp.sum(g * tan_w, axis=-1)  # dp/dw = r e
    k1 = jnp.sum(g * tan_b, axis=-1) / w0  # dp/dpsi = w r e'
    ring, turn = _sinusoid_min(k0, k1, db)
    # lateral (w = 1): exact ring minimum of the linearisation at u0, plus Taylor in u at every psi
    # (dp/du = L (1 + kappa r cos psi) t is parallel to the tangent t, so |g . dp/du| <= |g . t| (L + theta r)).
    stretch = length + theta * r
    speed_u = jnp.sqrt(jnp.sum(tan_a ** 2, axis=-1))
    lateral = ring - k0 - jnp.abs(slope_a) * stretch / speed_u * da - 0.5 * theta * stretch * da * da
    # disk (flat, p = centre + w r e): exact minimum of the linearisation over the annular sector
    flat = jnp.minimum((w0 - da) * ring, (w0 + da) * ring) - w0 * k0
    convex = value + jnp.where(disk, flat, lateral)
    lipschitz = value - jnp.where(disk, r * da + r * (w0 + da) * db, stretch * da + r * db)
    bound = jnp.maximum(convex, lipschitz)  # (C, K)
    pick = jnp.argmin(bound, axis=1)[:, None]
    turn, slope_a, ring = (jnp.take_along_axis(x, pick, axis=1)[:, 0] for x in (turn, slope_a, ring))
    da, disk = da[:, 0], disk[:, 0]
    step_a = jnp.where(disk, jnp.where(ring < 0, da, -da), jnp.where(slope_a > 0, -da, da))
    lowest = cells["coords"] + jnp.stack([jnp.where(disk, 0.0, step_a), turn, jnp.where(disk, step_a, 0.0)], -1)
    return jnp.min(value, axis=1), jnp.min(bound, axis=1), lowest


def surface_cell_bounds(arc, spec: RobotSpec, coords, half, disk, link, sdf: Callable):
    """The judge's per-cell bound, public so that it can be checked against dense sampling.

    Args:
      arc: (M, 3) arc lengths, m.  coords: (C, 3) cell centres (u, psi, w); half: (C, 2)
      half extents along (u or w, psi); disk: (C,) bool (disk cell: varies w at fixed u);
      link: (C,) int.  sdf: ``points (C, 3) -> (values (C, K), subgradients (C, K, 3))``,
      each column convex and 1-Lipschitz (e.g. :func:`box_sdf`).
    Returns:
      value (C,) at the cell centres and a lower bound (C,) of ``min_k f_k`` over each cell.
    """
    cells = {"coords": jnp.asarray(coords, jnp.float32), "half": jnp.asarray(half, jnp.float32),
             "disk": jnp.asarray(disk, bool), "link": jnp.asarray(link, jnp.int32)}
    pose = robot_pose(jnp.asarray(arc, jnp.float32), spec)
    return _cell_bounds(cell_geometry(cells, pose, spec), cells, sdf, spec)[:2]


def _cell_points(coords: jnp.ndarray, link: jnp.ndarray, pose: dict, spec: RobotSpec) -> jnp.ndarray:
    """World points (C, 3) of surface coordinates (C, 3) on links (C,)."""
    return frame_to_world(pose["frames"][link],
                          link_surface_points(coords, pose["theta"][link], pose["phi"][link], spec,
                                              spec.radius_of(link)))


def _split_robot_cells(cells: dict) -> dict:
    """Each cell -> _SPLIT x _SPLIT children, (C, ...) -> (C _SPLIT^2, ...)."""
    k = _SPLIT
    offsets = (2.0 * np.arange(k) + 1.0) / k - 1.0
    oa, ob = [x.ravel() for x in np.meshgrid(offsets, offsets, indexing="ij")]
    half = cells["half"]
    da = oa[None, :] * half[:, :1]  # (C, k^2)
    db = ob[None, :] * half[:, 1:]
    disk = cells["disk"][:, None]
    shift = jnp.stack([jnp.where(disk, 0.0, da), db, jnp.where(disk, da, 0.0)], axis=-1)
    n = k * k
    return {
        "coords": (cells["coords"][:, None, :] + shift).reshape(-1, 3),
        "half": jnp.repeat(half / k, n, axis=0),
        "link": jnp.repeat(cells["link"], n),
        "disk": jnp.repeat(cells["disk"], n),
    }


def _take(cells, index):
    return jax.tree_util.tree_map(lambda x: x[index], cells)


def _surface_minimum(sdf: Callable, pose: dict, coarse: dict, cells: dict, spec: RobotSpec):
    """Minimum over the robot surface S of ``min_k f_k`` (each convex, 1-Lipschitz) by fixed-size
    branch and bound: returns (best value, lower bound of the true minimum).

    Every level splits the ``_KEEP`` cells with the lowest bounds; the bounds of the cells not
    split stay in the lower bound. After the last level the function is also taken at the
    linear model's lowest point of its ``_KEEP`` lowest-bound cells (real robot points: minima
    often lie on a cell's border, e.g. a disk's rim).
    """

    def select(cells, value, bound, lowest, best, closed):
        _, index = jax.lax.top_k(-bound, _KEEP)
        closed = jnp.minimum(closed, jnp.min(bound.at[index].set(jnp.inf)))
        return (_take(cells, index), jnp.minimum(best, jnp.min(value)), closed, bound[index], lowest[index])

    def level(carry, _):
        children = _split_robot_cells(carry[0])
        value, bound, lowest = _cell_bounds(cell_geometry(children, pose, spec), children, sdf, spec)
        return select(children, value, bound, lowest, *carry[1:3]), None

    value, bound, lowest = _cell_bounds(coarse, cells, sdf, spec)
    carry = select(cells, value, bound, lowest, jnp.inf, jnp.inf)
    (kept, best, closed, kept_bound, kept_lowest), _ = jax.lax.scan(level, carry, None, length=_BOX_LEVELS)
    probe, _ = sdf(_cell_points(kept_lowest, kept["link"], pose, spec))
    return jnp.minimum(best, jnp.min(probe)), jnp.minimum(closed, jnp.min(kept_bound))


def _box_sdf_columns(box):
    """The box SDF of ``box`` (6,) as a one-column function for :func:`_cell_bounds`."""

    def sdf(points):
        value, g = box_sdf(points, box[:3], box[3:])
        return value[:, None], g[:, None]

    return sdf


def box_distances(arc, pose, coarse, boxes, cells, spec: RobotSpec):
    """Box distances (B,) and certificates (B,) (module docstring); boxes (B, 6) centre, half sizes."""

    def one(box):
        return _surface_minimum(_box_sdf_columns(box), pose, coarse, cells, spec)

    best, lower = jax.vmap(one)(boxes)
    inside = robot_signed_distance(boxes[:, :3], arc, spec)
    return jnp.minimum(best, inside), jnp.where(inside < best, 0.0, best - lower)


# ----------------------------------------------------------------------------- mesh distance


# ----------------------------------------------------------------------------- rigorous fallback


@functools.partial(jax.jit, static_argnums=(3,))
def _box_cells_chunk(cells, arc, box, spec: RobotSpec):
    """Value and bound of a box's SDF over robot-surface cells (fallback)."""
    geometry = cell_geometry(cells, robot_pose(arc, spec), spec)
    return _cell_bounds(geometry, cells, _box_sdf_columns(box), spec)[:2]


def exhaustive_box(box: np.ndarray, spec: RobotSpec, arc: np.ndarray) -> float:
    """Branch and bound without a size limit for a box (6,) (centre, half sizes): every cell whose
    bound is below ``best - CERTIFIED`` is split until none is left. Returns the minimum, m."""
    arc_j = jnp.asarray(arc, jnp.float32)
    box = jnp.asarray(box, jnp.float32)
    cells = coarse_robot_cells(spec)
    best = float(robot_signed_distance(box[None, :3], arc_j, spec)[0])
    while len(cells["link"]):
        count = len(cells["link"])
        values, bounds = [], []
        for start in range(0, count, _FALLBACK_CHUNK):
            chunk = _take(cells, np.arange(start, min(start + _FALLBACK_CHUNK, count)))
            pad = _FALLBACK_CHUNK - len(chunk["link"])
            chunk = jax.tree_util.tree_map(lambda x: np.concatenate([x, np.repeat(x[:1], pad, axis=0)]), chunk)
            v, b = _box_cells_chunk(chunk, arc_j, box, spec)
            values.append(np.asarray(v)[:_FALLBACK_CHUNK - pad])
            bounds.append(np.asarray(b)[:_FALLBACK_CHUNK - pad])
        values, bounds = np.concatenate(values), np.concatenate(bounds)
        best = min(best, float(values.min()))
        keep = _take(cells, np.nonzero(bounds < best - CERTIFIED)[0])
        cells = jax.tree_util.tree_map(np.asarray, _split_robot_cells(keep))
    return best
