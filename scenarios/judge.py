"""The judge of one control step: the exact distance along the continuous motion.

Arc lengths move linearly over a step and obstacles with their velocity. The bending vector
``ab_j`` of link j is linear in the arc lengths; a body point q moves with ``|dq/d ab_j| <= (arc
length from link j's base to q's backbone point) + r <= (M - j) L + r`` (0-indexed j): the
backbone frame at arc fraction sigma of link j is ``exp(sigma [w]x)`` with ``|w| = |ab_j|``, whose
differential has norm <= 1 (singular values 1 and ``2 sin(theta / 2) / theta``), so the frame
turns at most ``sigma |d ab_j|`` and the point's lever arm is at most the arc length after it plus
r. Over a step every robot point's path is at most ``sum_j |Delta ab_j| ((M - j) L + r)`` long
(:func:`robot_motion_bound`), a sphere's ``|v| dt``; ``substeps = ceil(max(both) / max_move)``
checks keep every point's path between two checks below ``max_move`` (2 cm). Each check is the
exact distance of :mod:`scenarios.truth`.
"""

from __future__ import annotations

import dataclasses
import functools
import math

import jax
import numpy as np

from ncedf.robot import RobotSpec, bending_vector
from ncedf.units import to_reference, unit
from scenarios.truth import check_state, true_distances_certified
from scenarios.world import World


@functools.partial(jax.jit, static_argnums=1)
def _bending_vector(arc, spec: RobotSpec):
    return bending_vector(arc, spec)


def robot_motion_bound(spec: RobotSpec, arc0, arc1) -> float:
    """Upper bound (m) on the path length of any robot body point while the arc lengths go
    linearly from ``arc0`` to ``arc1`` (M, 3): ``sum_j |Delta ab_j| ((M - j) L + r)``."""
    delta = check_state(arc1, spec) - check_state(arc0, spec)
    dab = np.asarray(_bending_vector(delta, spec), np.float64)  # linear in the arc lengths: the change of ab
    lever = (spec.n_links - np.arange(spec.n_links)) * spec.length + spec.thickest
    return float(np.sum(np.linalg.norm(dab, axis=-1) * lever))


def substep_count(world: World, spec: RobotSpec, arc0, arc1, dt: float, max_move: float = 0.02) -> int:
    """Checks per step (>= 1) so that no robot or obstacle point moves more than ``max_move`` (m)
    between two checks: ``ceil(max(robot_motion_bound, max |v| dt) / max_move)``."""
    if not max_move > 0:
        raise ValueError(f"max_move must be > 0, got {max_move!r}")
    if not dt >= 0:
        raise ValueError(f"dt must be >= 0, got {dt!r}")
    move = max(robot_motion_bound(spec, arc0, arc1), world.max_speed * dt)
    return max(1, math.ceil(move / max_move))


@dataclasses.dataclass(frozen=True)
class Judgement:
    """The exact check of one step (see :func:`judge_step`); distances in m, times in s."""

    min_distance: float
    first_collision_time: float | None
    substeps: int
    end_distance: float
    certificate: float = 0.0


@functools.lru_cache(maxsize=4)
def _reference_world(world: World, factor: float) -> World:
    """``world.scaled(factor)``, kept: a scaled mesh builds its hierarchy once, not every step."""
    return world.scaled(factor)


def judge_step(world: World, spec: RobotSpec, arc0, arc1, t0: float, dt: float) -> Judgement:
    """Judge the motion from ``arc0`` (M, 3) at ``t0`` to ``arc1`` at ``t0 + dt``.

    The exact distance is checked at ``substeps + 1`` instants ``t0 + i dt / substeps``
    (arc lengths interpolated linearly; :func:`substep_count` with its 2 cm default).
    ``first_collision_time`` is the first checked instant with distance < 0, else None;
    ``certificate`` how far above the truth any checked minimum may be (m). The robot and the world
    are judged in the robot's units (``ncedf.units``), so the 2 cm and the distances' certified
    tolerances are of the paper's robot and scale with a robot of another size.
    """
    u = unit(spec)
    if u == 1.0:
        return _judge(world, spec, arc0, arc1, t0, dt)
    ref = _judge(_reference_world(world, 1.0 / u), to_reference(spec), np.asarray(arc0, np.float64) / u,
                 np.asarray(arc1, np.float64) / u, t0, dt)
    return dataclasses.replace(ref, min_distance=ref.min_distance * u, end_distance=ref.end_distance * u,
                               certificate=ref.certificate * u)


def _judge(world: World, spec: RobotSpec, arc0, arc1, t0: float, dt: float) -> Judgement:
    """:func:`judge_step` as measured, in metres."""
    arc0, arc1 = check_state(arc0, spec), check_state(arc1, spec)
    n = substep_count(world, spec, arc0, arc1, dt)
    frac = np.arange(n + 1) / n
    arcs = arc0[None] + frac[:, None, None] * (arc1 - arc0)[None]
    times = t0 + frac * dt
    values, certificates = true_distances_certified(world, spec, arcs, times)
    if not values.shape[1]:
        return Judgement(math.inf, None, n, math.inf)
    d = values.min(axis=1)
    # the truth at an instant lies in [min_k (v_k - c_k), min_k v_k]
    certificate = float(np.max(d - (values - certificates).min(axis=1)))
    hit = np.nonzero(d < 0)[0]
    return Judgement(min_distance=float(d.min()), first_collision_time=float(times[hit[0]]) if len(hit) else None,
                     substeps=n, end_distance=float(d[-1]), certificate=certificate)
