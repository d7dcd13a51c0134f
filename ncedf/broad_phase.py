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

Selection rule (two stages, fixed sizes, so the program shape never changes):

1. Per horizon step ``k`` and link ``m``, over all rollouts: the mean capsule
   (the average over rollouts of the sub-arc end points ``a_s``, ``b_s``). The
   ``K1`` points nearest to the mean capsule's segments (smallest
   ``min_s dist(p, mean segment s)``) are the candidates of (k, m).
2. Per rollout state (j, k): for every link m and each of its K1 candidates,
   ``LB(p, m)`` from that state's own capsules; the ``K2`` (link, point) pairs
   with the smallest ``LB`` over all links are evaluated by the representation.
   The state's minimum distance is the minimum over those K2 values.

Masked (padding) points get an infinite bound and distance, so they are never
preferred over real points and never count.

Exactness: for the exact geometry the result equals the brute-force minimum
whenever the nearest (link, point) pair survives both stages; a sufficient
condition is that the found minimum is <= the smallest ``LB`` among the pairs
not selected. For a learned distance the network's own error enters; the
agreement is measured against brute force in ``bench/mppi_step.py``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from ncedf.robot import RobotSpec, _even_series, bending_vector, forward_kinematics


def link_capsules(arc: jnp.ndarray, spec: RobotSpec, segments: int, frames=None):
    """Bounding capsules of every link of one configuration.

    Args:
      arc: (M, 3) arc lengths, m.  segments: sub-arcs per link, S >= 1.
      frames: (M + 1, 4, 4) forward kinematics of ``arc`` if already computed.
    Returns:
      a, b: (M, S, 3) world end points of each sub-arc's chord, m;
      radius: (M,) capsule radius (sub-arc sagitta + r), m.
    """
    ab = bending_vector(arc, spec)  # (M, 2)
    frames = (forward_kinematics(arc, spec) if frames is None else frames)[:-1]  # (M, 4, 4)
    u = jnp.linspace(0.0, 1.0, segments + 1)  # (S + 1,)
    t_ab = ab[:, None, :] * u[None, :, None]  # (M, S + 1, 2) bending vector of the partial arc
    sinc, versc, _ = _even_series(jnp.sum(t_ab * t_ab, axis=-1))
    length = spec.length * u[None, :]
    local = jnp.stack([length * versc * t_ab[..., 0], length * versc * t_ab[..., 1], length * sinc], axis=-1)
    world = jnp.einsum("mij,msj->msi", frames[:, :3, :3], local) + frames[:, None, :3, 3]
    theta_sq = jnp.sum(ab * ab, axis=-1)
    half = jnp.sqrt(theta_sq) / (2.0 * segments)  # half the sub-arc angle
    _, versc_half, _ = _even_series(half * half)
    # sagitta = rho (1 - cos(alpha / 2)) = (L / S) (alpha / 2)^2 versc / alpha = (L / S) (alpha / 4) versc
    sagitta = (spec.length / segments) * (half / 2.0) * versc_half
    return world[:, :-1], world[:, 1:], sagitta + spec.radius


def segment_distance(p: jnp.ndarray, a: jnp.ndarray, b: jnp.ndarray) -> jnp.ndarray:
    """Distance from points ``p`` to segments ``[a, b]`` (broadcasting, last axis 3).

    Computed per component (structure of arrays) so XLA fuses it on CPU.
    """
    px, py, pz = p[..., 0], p[..., 1], p[..., 2]
    ax, ay, az = a[..., 0], a[..., 1], a[..., 2]
    ux, uy, uz = b[..., 0] - ax, b[..., 1] - ay, b[..., 2] - az
    vx, vy, vz = px - ax, py - ay, pz - az
    uu = jnp.maximum(ux * ux + uy * uy + uz * uz, 1e-12)
    t = jnp.clip((vx * ux + vy * uy + vz * uz) / uu, 0.0, 1.0)
    dx, dy, dz = vx - t * ux, vy - t * uy, vz - t * uz
    return jnp.sqrt(dx * dx + dy * dy + dz * dz)


def stage_one(a: jnp.ndarray, b: jnp.ndarray, points: jnp.ndarray, mask: jnp.ndarray, k1: int) -> jnp.ndarray:
    """Candidates per link for one horizon step, over all rollouts.

    Args:
      a, b: (N, M, S, 3) capsule segments of the N rollout states of this step.
      points: (P, 3); mask: (P,) bool.  k1: candidates per link (<= P).
    Returns:
      (M, k1) int indices into ``points``: the k1 points nearest to the mean
      (over rollouts) capsule segments of each link.
    """
    ma, mb = jnp.mean(a, axis=0), jnp.mean(b, axis=0)  # (M, S, 3)
    d = segment_distance(points[None, None, :, :], ma[:, :, None, :], mb[:, :, None, :])  # (M, S, P)
    d = jnp.where(mask[None, :], jnp.min(d, axis=1), jnp.inf)
    return jax.lax.top_k(-d, k1)[1]


def stage_two(a, b, radius, cand_points, cand_mask, k2: int):
    """The k2 (link, candidate) pairs of one rollout state with the smallest lower bound.

    Args:
      a, b: (M, S, 3) this state's capsule segments; radius: (M,).
      cand_points: (M, K1, 3) the step's candidates per link; cand_mask (M, K1).
      k2: pairs to keep (<= M * K1).
    Returns:
      link (k2,) and slot (k2,) int: pair i is candidate ``slot[i]`` of link ``link[i]``.
    """
    d = segment_distance(cand_points[:, None, :, :], a[:, :, None, :], b[:, :, None, :])  # (M, S, K1)
    lb = jnp.min(d, axis=1) - radius[:, None]
    lb = jnp.where(cand_mask, lb, jnp.inf)
    k1 = cand_points.shape[1]
    flat = jax.lax.top_k(-lb.reshape(-1), k2)[1]
    return flat // k1, flat % k1


def rollout_min_distances_broad(shape, arcs, points, mask, k1: int, k2: int, segments: int, frames=None):
    """Per-state minimum distance by the broad phase.

    Args:
      shape: a representation from ``ncedf.shapes``.
      arcs: (N, H, M, 3) rollout states.  points: (P, 3); mask: (P,) bool.
      k1, k2, segments: see the module docstring (clamped to the point count).
      frames: (N, H, M + 1, 4, 4) forward kinematics of ``arcs`` if already computed.
    Returns:
      (N, H) minimum distance of each state, m (+inf if every point is masked).
    """
    spec = shape.spec
    n_points = points.shape[0]
    n_links = arcs.shape[-2]
    k1 = max(1, min(k1, n_points))
    k2 = max(1, min(k2, n_links * k1))
    if frames is None:
        frames = forward_kinematics(arcs, spec)
    a, b, radius = jax.vmap(jax.vmap(lambda x, f: link_capsules(x, spec, segments, f)))(arcs, frames)

    def per_step(args):
        arcs_k, frames_k, a_k, b_k, r_k = args  # (N, M, 3), (N, M + 1, 4, 4), (N, M, S, 3), ..., (N, M)
        idx = stage_one(a_k, b_k, points, mask, k1)  # (M, K1)
        cand = points[idx]
        cand_mask = mask[idx]

        def per_state(arc, ff, aa, bb, rr):
            link, slot = stage_two(aa, bb, rr, cand, cand_mask, k2)
            pidx = idx[link, slot]
            geom = shape.prepare(arc, ff)
            d = shape.pair_distances(geom, points[pidx], link)
            return jnp.min(jnp.where(mask[pidx], d, jnp.inf))

        return jax.vmap(per_state)(arcs_k, frames_k, a_k, b_k, r_k)

    swap = lambda x: jnp.swapaxes(x, 0, 1)  # noqa: E731
    out = jax.lax.map(per_step, (swap(arcs), swap(frames), swap(a), swap(b), swap(radius)))  # (H, N)
    return out.T


def rollout_min_distances_brute(shape, arcs, points, mask):
    """Reference: every point against every link of every state, (N, H), m.

    A loop over the horizon (``lax.map``) with the rollouts vectorised inside;
    cheaper than materialising all N * H * M * P inputs at once.
    """

    def per_step(arcs_k):
        return jax.vmap(lambda x: shape.min_distance(points, x, mask))(arcs_k)

    return jax.lax.map(per_step, jnp.swapaxes(arcs, 0, 1)).T
