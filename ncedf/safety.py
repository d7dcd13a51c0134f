"""The safety-filter stage: the executed action checked over its step before it runs.

MPPI scores the rollout states ``x^1 .. x^H`` only, ``dt`` apart, so a link can
sweep through a thin obstacle within one step and look safe at both ends. The
filter checks the executed action at ``substeps`` states evenly spaced over the
step (``x + s/S u dt``, s = 1..S) against the cloud and the obstacle model
(:func:`step_clearance`). Candidates, in order of preference: the MPPI action,
the lowest-cost sample's first control, the first control of the sample
farthest from the obstacles after one step, the MPPI action scaled by
``CHECK_SCALES``, and no motion. The first whose clearance over the step is at
least the safety margin is executed; if none is, the one with the largest
clearance. The fallbacks are evaluated only when the MPPI action fails.

Two options act on the MPPI step around the check:

* ``sweep_first``: each rollout's first state is scored by that same clearance
  over its step, so the update does not follow a sample that sweeps through an
  obstacle and out again within ``dt`` (the check would refuse it);
* ``follow_executed``: the next step is warm-started from the executed
  candidate's controls instead of the refused plan. A refused plan saturated
  towards an obstacle otherwise stays the warm start: every sample around it
  crosses the obstacle, their collision costs all sit at the ceiling, and the
  robot holds still for as long as the obstacle stays.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from ncedf.broad_phase import BroadPhase, rollout_min_distances
from ncedf.obstacle_model import model_clearance
from ncedf.robot import RobotSpec, forward_kinematics
from ncedf.validate import check_fields

#: Scales of the MPPI action among the check's candidates (before "no motion").
CHECK_SCALES = (0.5, 0.25)


@dataclasses.dataclass(frozen=True)
class SafetyFilter:
    """The check of the executed action (module docstring).

    Attributes:
      substeps: states checked over the step.
      sweep_first: score each rollout's first state over its step.
      follow_executed: warm-start from the executed candidate's controls.
    """

    substeps: int = 4
    sweep_first: bool = False
    follow_executed: bool = False

    def __post_init__(self):
        check_fields(self, integers=("substeps",), flags=("sweep_first", "follow_executed"))


def step_clearance(dt: float, substeps: int, broad: BroadPhase | None, shape, arc: jnp.ndarray,
                   actions: jnp.ndarray, points, mask, model=None, shared: bool = False) -> jnp.ndarray:
    """Predicted clearance over one step for each action: min over the states
    ``arc + (s / S) u dt``, s = 1..S (``substeps``), of the representation's min distance to the
    cloud (broad phase, or brute force where ``broad`` is None) and of the clearance to the
    fitted obstacle model if given (a grid, and each moving polytope anywhere its speed takes it
    by the substep's time: an obstacle seen moving may turn within the step).

    Args:
      arc: (M, 3) m.  actions: (C, M, 3) m/s.  points: (P, 3) m; mask: (P,) bool, or (M, P) for the
        points each link counts (``ncedf.mount``).
      shared: False = the broad phase picks points for each action apart (the check's few
        candidates, which can move apart); True = for all actions at once (many actions from
        one state, as for the rollouts).
    Returns:
      (C,) m (+inf for an empty cloud and no model).
    """
    frac = jnp.arange(1, substeps + 1, dtype=arc.dtype) / substeps
    states = arc + dt * frac[None, :, None, None] * actions[:, None]  # (C, S, M, 3)
    if shared:
        clearance = jnp.min(rollout_min_distances(broad, shape, states, points, mask), axis=1)
    else:
        one = lambda s: jnp.min(rollout_min_distances(broad, shape, s[None], points, mask))  # noqa: E731
        clearance = jax.vmap(one)(states)
    if model is not None:
        frames = forward_kinematics(states, shape.spec)
        ahead = model_clearance(model, states, frames, shape.spec, dt * frac, turning=True)  # (C, S)
        clearance = jnp.minimum(clearance, jnp.min(ahead, axis=1))
    return clearance


def limit_to_state_bounds(arc: jnp.ndarray, u: jnp.ndarray, dt: float, spec: RobotSpec) -> jnp.ndarray:
    """Scale each link's rate (keeping the zero sum) so ``arc + u dt`` stays in the limits.

    ``arc`` (M, 3) is assumed within the limits; returns u (M, 3) scaled per link by the largest
    factor in [0, 1] that keeps every chamber in [l_min, l_max].
    """
    step = u * dt
    room = jnp.where(step > 0, spec.l_max - arc, arc - spec.l_min)
    room = jnp.maximum(room, 0.0)
    ratio = jnp.where(jnp.abs(step) > 0, room / jnp.maximum(jnp.abs(step), 1e-30), jnp.inf)
    return u * jnp.minimum(1.0, jnp.min(ratio, axis=-1, keepdims=True))


def first_passing(check, candidates: jnp.ndarray, needed) -> tuple[jnp.ndarray, jnp.ndarray]:
    """The candidates (C, M, 3) checked in order until one's clearance ``check(actions (1, M, 3))``
    reaches ``needed`` (a while loop: the fallbacks run only when the first fails, and the program
    holds one copy of the check). Returns the chosen index and its clearance."""

    def unchecked(carry):
        i, clear = carry
        return (i < len(candidates)) & ((i == 0) | (clear[i - 1] < needed))

    def check_next(carry):
        i, clear = carry
        return i + 1, clear.at[i].set(check(candidates[i][None])[0])

    clear = jnp.full(len(candidates), -jnp.inf, candidates.dtype)
    _, clear = jax.lax.while_loop(unchecked, check_next, (jnp.asarray(0), clear))
    ok = clear >= needed
    choice = jnp.where(jnp.any(ok), jnp.argmax(ok), jnp.argmax(clear))
    return choice, clear[choice]


def filtered_action(safety: SafetyFilter, check, spec: RobotSpec, arc, dt: float, margin: float, updated, raw,
                    bounded, best, safest):
    """The executed action after the check, its clearance, the candidate chosen (0 = the MPPI
    action) and the next warm start.

    Args:
      check: ``actions (C, M, 3) -> (C,)`` clearance over the step (:func:`step_clearance` bound).
      updated: (H, M, 3) the bounded plan; raw: (H, M, 3) the plan kept as the warm start.
      bounded: (N, H, M, 3) the bounded samples; best, safest: indices of the lowest-cost sample
        and of the sample farthest from the obstacles after one step.
    """
    zero = jnp.zeros_like(updated)
    plans = jnp.stack([updated, bounded[best], bounded[safest]] + [s * updated for s in CHECK_SCALES] + [zero])
    candidates = jax.vmap(lambda a: limit_to_state_bounds(arc, a, dt, spec))(plans[:, 0])
    choice, clearance = first_passing(check, candidates, margin)
    if safety.follow_executed:
        raw = jnp.where(choice == 0, raw, plans[choice])
    return candidates[choice], clearance, choice, raw
