"""Broad phase for the MPPI collision cost: which (link, obstacle point) pairs to evaluate.

The collision cost of a rollout state needs only ``min_p Gamma(p, q)``. The
broad phase picks, per rollout state, a few (link, point) pairs that can hold
that minimum, from cheap geometric bounds, and the shape representation (the
network, for N-CEDF) is evaluated on those pairs only.

Bounding capsules. Split link ``m`` into ``S`` sub-arcs of equal length ``L / S``
and angle ``theta / S``; sub-arc ``s`` runs from ``a_s`` to ``b_s`` (backbone
points). A circular arc of angle ``alpha <= pi`` lies within its sagitta
``rho (1 - cos(alpha / 2))`` (``rho = L / theta``) of its chord *segment*, and
the link body (tube of radius r and the end disks) lies within ``r`` of the
backbone. So the link body is inside the union of the capsules
``{x : dist(x, [a_s, b_s]) <= R}``, ``R = sagitta(theta / S) + r``, and for every
point ``p`` the *exact* distance to the link is ``>= LB(p, m) = min_s dist(p,
[a_s, b_s]) - R``. (Valid for ``theta / S <= pi``; robots here bend at most
``spec.max_bend()`` ~ 2.3 rad per link.)

The selection, in two stages of fixed sizes (so the program shape never
changes):

1. Per horizon step ``k`` and link ``m``, over all rollouts: the mean capsule
   (the average over rollouts of the sub-arc end points ``a_s``, ``b_s``). The
   ``K1`` points nearest to the mean capsule's segments (smallest
   ``min_s dist(p, mean segment s)``) are the candidates of (k, m). This costs
   H * M * S * P segment distances, independent of the sample count.
2. Per rollout state (j, k): for every link m and each of its K1 candidates,
   ``LB(p, m)`` from that state's own capsules; the ``K2`` (link, point) pairs
   with the smallest ``LB`` over all links are evaluated by the representation.
   The state's minimum distance is the minimum over those K2 values.

Cost on CPU (XLA): ``top_k``, ``argmin`` and sorts over many short rows cost
microseconds per row, about as much as the network. So stage 2 uses neither:
the K2 smallest bounds are found exactly by (a) the minimum of each group of 8
candidates, fused with the bound computation (no (N, H, M, K1) array is
stored), (b) the K2 groups with the smallest minima (the K2 smallest bounds
lie in them), (c) the K2 smallest of those K2 * 8 bounds; (b) and (c) are K2
passes of a plain ``min`` over keys that carry the position in their low
mantissa bits (:func:`smallest`). Everything is per component (x, y, z as
separate arrays) with the candidates on the last axis, for all N x H states at
once. Forward kinematics comes in as frames (the MPPI computes them once for
the goal cost too). Measured step times: ``bench/mppi_step.py``.

The candidates of the average miss the nearest points of rollouts far from
it, whose distances are then over-estimated; the share grows with the
observed density (the candidates cover a fixed number of points, so a smaller
area): ``bench/broad_phase.py`` measures it against brute force.

Masked (padding) points get an infinite bound and distance, so they are never
preferred over real points and never count.

Exactness: for the exact geometry the result equals the brute-force minimum
whenever the nearest (link, point) pair survives both stages; a sufficient
condition is that the found minimum is <= the smallest ``LB`` among the pairs
not selected. For a learned distance the network's own error enters; the
agreement is measured against brute force in ``bench/mppi_step.py``.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from ncedf.robot import RobotSpec, arc_sagitta, bending_vector, even_series, forward_kinematics
from ncedf.validate import check_fields


@dataclasses.dataclass(frozen=True)
class BroadPhase:
    """The broad phase's sizes (module docstring).

    Attributes:
      k1: candidate points per (horizon step, link).
      k2: (link, point) pairs evaluated per rollout state.
      capsule_segments: sub-arc capsules per link. Three capsules bound a link tighter than two
        (the sagitta of a third of the arc), so fewer pairs hold the minimum: with 6 pairs the
        rollout minima agree with brute force about as often as with 12 pairs of two capsules
        (``bench/mppi_step.py``).
    """

    k1: int = 128
    k2: int = 6
    capsule_segments: int = 3

    def __post_init__(self):
        check_fields(self, integers=("k1", "k2", "capsule_segments"))


def capsule_points(arcs: jnp.ndarray, frames: jnp.ndarray, spec: RobotSpec, segments: int):
    """Backbone points bounding the sub-arc chords of every link, per component.

    Args:
      arcs: (..., M, 3) arc lengths, m.  frames: (..., M + 1, 4, 4) their forward kinematics.
      segments: sub-arcs per link, S >= 1.
    Returns:
      xyz: tuple of 3 arrays (..., M, S + 1): world backbone points at arc
      fractions 0, 1/S, .., 1 (sub-arc s runs from point s to point s + 1), m;
      radius: (..., M) capsule radius (sub-arc sagitta + r), m.
    """
    ab = bending_vector(arcs, spec)  # (..., M, 2)
    u = jnp.linspace(0.0, 1.0, segments + 1, dtype=ab.dtype)  # (S + 1,)
    ta, tb = ab[..., 0:1] * u, ab[..., 1:2] * u  # (..., M, S + 1) bending vector of the partial arc
    sinc, versc, _ = even_series(ta * ta + tb * tb)
    length = spec.length * u
    local = (length * versc * ta, length * versc * tb, length * sinc)
    base = frames[..., :-1, :, :]  # (..., M, 4, 4)
    xyz = tuple(
        base[..., i, 0:1] * local[0] + base[..., i, 1:2] * local[1] + base[..., i, 2:3] * local[2] + base[..., i, 3:4]
        for i in range(3)
    )
    theta = jnp.sqrt(ab[..., 0] * ab[..., 0] + ab[..., 1] * ab[..., 1])
    return xyz, arc_sagitta(theta / segments, spec.length / segments) + spec.radius_of()


def _segment_distance_c(px, py, pz, ax, ay, az, bx, by, bz):
    """Distance from points to segments [a, b], per component (broadcasting)."""
    ux, uy, uz = bx - ax, by - ay, bz - az
    vx, vy, vz = px - ax, py - ay, pz - az
    uu = jnp.maximum(ux * ux + uy * uy + uz * uz, 1e-12)
    t = jnp.clip((vx * ux + vy * uy + vz * uz) / uu, 0.0, 1.0)
    dx, dy, dz = vx - t * ux, vy - t * uy, vz - t * uz
    return jnp.sqrt(dx * dx + dy * dy + dz * dz)


def _capsule_distance(p, xyz, segments: int):
    """min over sub-arcs s of dist(p, [point s, point s + 1]); ``p`` and ``xyz`` broadcast per component."""
    out = None
    for s in range(segments):
        d = _segment_distance_c(*p, *(c[..., s] for c in xyz), *(c[..., s + 1] for c in xyz))
        out = d if out is None else jnp.minimum(out, d)
    return out


def pair_mask(mask: jnp.ndarray, link, point) -> jnp.ndarray:
    """Whether each (link, point) pair counts, by ``mask`` (P,) or per link (M, P) (``ncedf.mount``);
    ``link`` and ``point`` broadcast."""
    return mask[point] if mask.ndim == 1 else mask[link, point]


def stage_one(xyz, points: jnp.ndarray, mask: jnp.ndarray, k1: int, segments: int) -> jnp.ndarray:
    """Candidates per (horizon step, link), over all rollouts.

    Args:
      xyz: 3 arrays (N, H, M, S + 1): capsule backbone points of the rollout states.
      points: (P, 3); mask: (P,) or (M, P) bool.  k1: candidates per link (<= P).
    Returns:
      (H, M, k1) int indices into ``points``: the k1 points nearest to the mean
      (over rollouts) capsule segments of each (step, link).
    """
    mean = tuple(jnp.mean(c, axis=0)[..., None, :] for c in xyz)  # (H, M, 1, S + 1)
    d = _capsule_distance((points[:, 0], points[:, 1], points[:, 2]), mean, segments)  # (H, M, P)
    d = jnp.where(mask, d, jnp.inf)
    return jax.lax.top_k(-d, k1)[1]


def _pack(values: jnp.ndarray, offset) -> tuple[jnp.ndarray, jnp.ndarray]:
    """Keys that carry each entry's position along the last axis in their low mantissa bits.

    ``values + offset`` (made >= 0; ``offset`` must bound ``-values`` from
    above) keeps its float order in its bit pattern, whose lowest ``ceil(log2
    n)`` bits are replaced by the position. Non-finite entries become 1e30.
    Returns the keys (float32, same shape) and the mask of the position bits.
    """
    n = values.shape[-1]
    slot_bits = max(1, (n - 1).bit_length())
    low = jnp.int32((1 << slot_bits) - 1)
    v = jnp.clip(values.astype(jnp.float32) + offset, 0.0, 1e30)  # +inf and NaN -> 1e30 (NaN: clip keeps NaN)
    v = jnp.where(jnp.isnan(v), 1e30, v)
    bits = jax.lax.bitcast_convert_type(v, jnp.int32)
    return jax.lax.bitcast_convert_type((bits & ~low) | jnp.arange(n, dtype=jnp.int32), jnp.float32), low


def smallest(values: jnp.ndarray, k: int, offset: float = 0.0) -> jnp.ndarray:
    """Positions of the k smallest entries along the last axis, (..., k), smallest first.

    ``argmin`` and ``top_k`` are many times slower on CPU than a plain ``min``.
    So the position is packed into the value (:func:`_pack`); k passes of a
    fused ``min`` (each over the entries above the previous one) then give
    values and positions at once. The packing moves a value by at most ``n``
    units in the last place (about 2e-5 m at 1 m for n = 128), which only
    reorders nearly tied bounds. Non-finite entries rank last; if fewer than k
    entries are finite, the remaining positions are arbitrary valid positions
    (harmless for a minimum over the selected pairs).
    """
    n = values.shape[-1]
    if k >= n:
        return jnp.broadcast_to(jnp.arange(n, dtype=jnp.int32), values.shape[:-1] + (n,))
    keys, low = _pack(values, offset)

    def one_pass(prev, _):
        cur = jnp.min(jnp.where(keys > prev[..., None], keys, jnp.inf), axis=-1)
        return cur, cur

    # A loop rather than k unrolled passes: the same work, a much smaller program to compile.
    first = jnp.min(keys, axis=-1)
    _, rest = jax.lax.scan(one_pass, first, None, length=k - 1)
    out = jnp.concatenate([first[None], rest], axis=0)  # (k, ...)
    pos = jax.lax.bitcast_convert_type(jnp.moveaxis(out, 0, -1), jnp.int32) & low
    return jnp.minimum(pos, n - 1)


def stage_two(xyz, radius, idx, points, mask, k2: int, segments: int, offset: float, group: int = 8):
    """The k2 (link, candidate) pairs of every rollout state with the smallest lower bound.

    ``LB(p, m)`` (the state's own sub-arc capsules) over all M * K1 candidates
    of the step; the k2 smallest are found exactly in two rounds: the
    candidates of each link are cut into groups of ``group``; the k2 smallest
    bounds lie in the k2 groups with the smallest minima (a group holding one
    of them has a minimum no larger than it, and at most k2 - 1 bounds are
    smaller), so only those k2 * group bounds are ranked again. The group
    minima fuse with the bound computation: no (N, H, M, K1) array is stored.

    Args:
      xyz: 3 arrays (N, H, M, S + 1): capsule backbone points; radius: (N, H, M).
      idx: (H, M, K1) candidates of each (step, link).  points (P, 3), mask (P,) or (M, P).
      offset: bounds the capsule radii from above (a sagitta is at most L / 2): r + L.
    Returns:
      link (N, H, k2) and point index (N, H, k2) of the selected pairs.
    """
    n_steps, n_links, k1 = idx.shape
    g = group if k1 % group == 0 and k1 > group else 1
    n_groups = k1 // g
    k2 = min(k2, n_links * n_groups)
    gidx = idx.reshape(n_steps, n_links, n_groups, g)
    cand = tuple(points[gidx, i][None] for i in range(3))  # (1, H, M, G, g)
    d = _capsule_distance(cand, tuple(c[..., None, None, :] for c in xyz), segments)  # (N, H, M, G, g)
    d = jnp.where(pair_mask(mask, jnp.arange(n_links)[:, None, None], gidx), d - radius[..., None, None], jnp.inf)
    gmin = jnp.min(d, axis=-1).reshape(d.shape[:2] + (n_links * n_groups,))
    best = smallest(gmin, k2, offset=offset)  # (N, H, k2) flat group index
    link = best // n_groups
    groups = jnp.broadcast_to(idx.reshape(n_steps, n_links * n_groups, g), gmin.shape[:2] + (n_links * n_groups, g))
    pid = jnp.take_along_axis(groups, best[..., None], axis=2)  # (N, H, k2, g)
    if g == 1:
        return link, pid[..., 0]
    p = tuple(points[pid, i] for i in range(3))
    ends = tuple(jnp.take_along_axis(c, link[..., None], axis=2)[..., None, :] for c in xyz)  # (N, H, k2, 1, S + 1)
    d = _capsule_distance(p, ends, segments) - jnp.take_along_axis(radius, link, axis=2)[..., None]
    d = jnp.where(pair_mask(mask, link[..., None], pid), d, jnp.inf).reshape(d.shape[:2] + (k2 * g,))
    pick = smallest(d, k2, offset=offset)  # (N, H, k2)
    return jnp.take_along_axis(link, pick // g, axis=-1), jnp.take_along_axis(pid.reshape(d.shape), pick, axis=-1)


def rollout_min_distances_broad(shape, arcs, points, mask, k1: int, k2: int, segments: int, frames=None):
    """Per-state minimum distance by the broad phase.

    Args:
      shape: a representation from ``ncedf.shapes``.
      arcs: (N, H, M, 3) rollout states.  points: (P, 3); mask: (P,) or per link (M, P) bool.
      k1, k2, segments: see the module docstring (clamped to the point count).
      frames: (N, H, M + 1, 4, 4) forward kinematics of ``arcs`` if already computed.
    Returns:
      (N, H) minimum distance of each state, m (+inf if every point is masked).
    """
    spec = shape.spec
    k1 = max(1, min(k1, points.shape[0]))
    k2 = max(1, min(k2, arcs.shape[-2] * k1))
    if frames is None:
        frames = forward_kinematics(arcs, spec)
    xyz, radius = capsule_points(arcs, frames, spec, segments)  # 3 x (N, H, M, S + 1), (N, H, M)
    idx = stage_one(xyz, points, mask, k1, segments)  # (H, M, K1)
    link, pidx = stage_two(xyz, radius, idx, points, mask, k2, segments, spec.thickest + spec.length)  # (N, H, K2)
    d = shape.state_pair_distances(arcs, frames, points[pidx], link)  # (N, H, K2)
    return jnp.min(jnp.where(pair_mask(mask, link, pidx), d, jnp.inf), axis=-1)


def rollout_min_distances_brute(shape, arcs, points, mask):
    """Reference: every point against every link of every state, (N, H), m.

    A loop over the horizon (``lax.map``) with the rollouts vectorised inside;
    cheaper than materialising all N * H * M * P inputs at once.
    """

    def per_step(arcs_k):
        return jax.vmap(lambda x: shape.min_distance(points, x, mask))(arcs_k)

    return jax.lax.map(per_step, jnp.swapaxes(arcs, 0, 1)).T


def rollout_min_distances(broad: BroadPhase | None, shape, arcs, points, mask, frames=None):
    """(N, H) min distance of each rollout state (N, H, M, 3) to the cloud (P, 3) with mask (P,) or
    per link (M, P), m: by the broad phase, or by brute force where ``broad`` is None."""
    if broad is None:
        return rollout_min_distances_brute(shape, arcs, points, mask)
    return rollout_min_distances_broad(shape, arcs, points, mask, broad.k1, broad.k2, broad.capsule_segments,
                                       frames)
