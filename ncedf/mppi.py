"""The MPPI core (paper Sec. V): sample, roll out, cost, weight, update, shift.

Dynamics (paper eq. 3) on the arc lengths: ``x' = x + u dt``. Each step draws N
perturbations of the plan ``U`` (H, M, 3), bounds them to zero-sum rates (the
sampling stage, ``ncedf.sampling``), rolls them out to the states
``x^1 .. x^H`` and charges each sample (paper Sec. V-B):

* goal: ``w_goal * ||T_ee(x^k) - T_G||_F`` for a pose goal (4, 4), or
  ``w_goal * ||p_ee(x^k) - p_G||`` for a position goal (3,) (two compiled
  variants, by the goal's shape). With ``goal_reach`` a running state is
  charged the closest goal distance of its rollout so far: an episode ends at
  the first reach, so a rollout is not charged for drifting on after it;
* collision: ``w_coll / max(d(x^k) - delta_s, epsilon)`` with ``d`` the least
  predicted distance to the obstacles (the cloud through the robot's shape
  representation, and the obstacle model where there is one); with the guide
  stage (``ncedf.guide``) the goal's position distance is measured along free space;
* state: ``w_state * sum over links and chambers of (l_min - l)_+ + (l - l_max)_+``;
* the release's terminal weights at ``x^H`` and its control-perturbation cost
  ``w_perturbation * sum_k U_k . eps_k / sigma^2`` (0 in the paper).

The paper sums ``k = 0 .. H-1``; the ``k = 0`` term is the same for every sample
and cannot change the normalised weights, so it is left out. The weights are
``exp(-C~ / lambda)`` of the costs normalised to [0, 1], lambda from the
temperature stage (``ncedf.temperature``); the update is
``U <- (1 - alpha_u) U + alpha_u sum_j w_j u^j / sum_j w_j``; the first control
is executed (scaled per link to keep the arc lengths within their limits) and
the plan shifts by one step, its last control repeated. At a step with no goal
distance tracked yet (the first) the plan may be updated ``first_iterations``
times before its first control is executed (:func:`first_plan`).

The core also tracks progress: the smallest goal distance of the current state
so far and the steps since it last fell by ``progress``. The temperature
stage's stall escape and the route recovery (``ncedf.recovery``) read it.

:func:`mppi_step` is the pure jitted step over a composed
``ncedf.controller.ControllerConfig``; ``ncedf.controller.Controller`` is the
validating shell around it.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp

from ncedf.broad_phase import rollout_min_distances
from ncedf.guide import guided_distance
from ncedf.obstacle_model import model_clearance
from ncedf.robot import RobotSpec, forward_kinematics
from ncedf.safety import filtered_action, limit_to_state_bounds, step_clearance
from ncedf.sampling import bounded_controls, sample_noise, update_plan
from ncedf.validate import check_fields


@dataclasses.dataclass(frozen=True)
class MPPIConfig:
    """The core's settings; defaults are the paper's (Sec. VI-A).

    Attributes:
      samples: rollouts N.  horizon: H steps.
      covariance: sampling covariance sigma^2 (Sigma = sigma^2 I), (m/s)^2.
      alpha_u: smoothing of the update, in (0, 1].
      w_goal, w_coll, w_state: cost weights.
      w_goal_terminal, w_coll_terminal: weights at x^H (release: 22, 1.1).
      w_perturbation: control-perturbation cost weight (release: 0.1).
      goal_reach: charge each running state its rollout's closest goal distance so far.
      safety_margin: delta_s, m.  epsilon: floor of the collision-cost denominator, m.
      control_bound: largest |rate|, m/s.  dt: step, s.
      max_points: obstacle-cloud capacity (clouds are padded to it with a mask).
      progress: the fall of the best goal distance that counts as progress, m (or Frobenius
        units for a pose goal).
      first_iterations: updates of the plan at a step with no goal distance tracked yet (the
        first): the zero plan's single update averages noise into a slow start.
    """

    samples: int = 800
    horizon: int = 20
    covariance: float = 0.05
    alpha_u: float = 1.0
    w_goal: float = 12.0
    w_coll: float = 1.1
    w_state: float = 50.0
    w_goal_terminal: float = 0.0
    w_coll_terminal: float = 0.0
    w_perturbation: float = 0.0
    goal_reach: bool = False
    safety_margin: float = 0.05
    epsilon: float = 0.01
    control_bound: float = 0.3
    dt: float = 0.05
    max_points: int = 512
    progress: float = 0.05
    first_iterations: int = 1

    def __post_init__(self):
        check_fields(self, integers=("samples", "horizon", "max_points", "first_iterations"), fractions=("alpha_u",),
                     positive=("covariance", "epsilon", "control_bound", "dt", "progress"),
                     non_negative=("w_goal", "w_coll", "w_state", "w_goal_terminal", "w_coll_terminal",
                                   "w_perturbation", "safety_margin"),
                     flags=("goal_reach",))


class MPPIState(NamedTuple):
    """The jitted step's state (a pytree): the plan (H, M, 3) m/s (with the sampling stage's
    ``unclipped`` the unbounded plan), a PRNG key, the smallest goal distance of the current
    state so far (scalar, +inf at first) and the steps since it last fell by ``progress``
    (scalar int32)."""

    nominal: jnp.ndarray
    key: jnp.ndarray
    best_goal: jnp.ndarray
    stalled: jnp.ndarray


class MPPIInfo(NamedTuple):
    """Diagnostics of one step (a pytree of arrays).

    plan: (H + 1, 3) end-effector positions along the updated plan, from the current state, m.
    predicted_min_distance: min over x^1..x^H of the selected rollout's predicted distance
      (selected = the lowest-cost sample), m.
    current_min_distance: predicted min distance from the current state to the observed cloud, m.
    cost_goal, cost_coll, cost_state, cost_perturbation: the selected rollout's weighted terms.
    cost_min, cost_max: the range of total costs over the samples.
    ess: effective sample size of the weights, ``1 / sum w^2`` (w normalised).
    selected: index of the selected rollout.
    rollout_min_distance: (N, H) predicted min distance of every rollout state, m.
    temperature: the lambda used.
    action_clearance: the safety filter's predicted clearance over the executed step (NaN
      without a filter), m.
    action_choice: the executed candidate of the safety filter (0 = the MPPI action).
    """

    plan: jnp.ndarray
    predicted_min_distance: jnp.ndarray
    current_min_distance: jnp.ndarray
    cost_goal: jnp.ndarray
    cost_coll: jnp.ndarray
    cost_state: jnp.ndarray
    cost_perturbation: jnp.ndarray
    cost_min: jnp.ndarray
    cost_max: jnp.ndarray
    ess: jnp.ndarray
    selected: jnp.ndarray
    rollout_min_distance: jnp.ndarray
    temperature: jnp.ndarray
    action_clearance: jnp.ndarray
    action_choice: jnp.ndarray


def init_state(spec: RobotSpec, config: MPPIConfig, key) -> MPPIState:
    """Zero plan (paper: the initial reference is zero), the key, no goal distance yet."""
    return MPPIState(jnp.zeros((config.horizon, spec.n_links, 3), jnp.float32), jnp.asarray(key),
                     jnp.asarray(jnp.inf, jnp.float32), jnp.asarray(0, jnp.int32))


def goal_distance(frames_ee: jnp.ndarray, goal: jnp.ndarray, guide=None) -> jnp.ndarray:
    """Goal cost distance: Frobenius ``||T_ee - T_G||`` for a pose goal (4, 4), else
    ``||p_ee - p_G||`` for a position goal (3,); ``frames_ee`` (..., 4, 4) -> (...,). With a
    ``guide`` field (``ncedf.guide``) the position's distance is the guided one."""
    if guide is None and goal.shape == (4, 4):
        return jnp.sqrt(jnp.sum((frames_ee - goal) ** 2, axis=(-2, -1)))
    if guide is None:
        return jnp.sqrt(jnp.sum((frames_ee[..., :3, 3] - goal) ** 2, axis=-1))
    guided = guided_distance(guide, frames_ee[..., :3, 3])
    if goal.shape == (4, 4):  # the rotation's share, and the guided position's
        return jnp.sqrt(jnp.sum((frames_ee[..., :3, :3] - goal[:3, :3]) ** 2, axis=(-2, -1)) + guided**2)
    return guided


def state_distances(config, shape, arc, arcs, frames, first, points, mask, model):
    """(N, H) predicted distance of each rollout state (N, H, M, 3) to the obstacles: the cloud
    (P, 3) with mask (P,), the fitted obstacle model (its polytopes moved to the state's time), and
    with the safety filter's ``sweep_first`` the first state scored over its step (its controls
    ``first`` (N, M, 3)), m."""
    c = config.mppi
    dist = rollout_min_distances(config.broad_phase, shape, arcs, points, mask, frames)
    if model is not None:
        ahead = c.dt * jnp.arange(1, c.horizon + 1, dtype=arcs.dtype)  # the times of x^1 .. x^H, s
        dist = jnp.minimum(dist, model_clearance(model, arcs, frames, shape.spec, ahead))
    if config.safety is not None and config.safety.sweep_first:
        swept = step_clearance(c.dt, config.safety.substeps, config.broad_phase, shape, arc, first, points, mask,
                               model, shared=True)
        dist = dist.at[:, 0].min(swept)
    return dist


def cost_terms(c: MPPIConfig, spec: RobotSpec, arcs, goal_d, dist, nominal, eps):
    """Per-sample weighted costs (N,) each: goal, collision, state, perturbation (module
    docstring), from the states (N, H, M, 3), their goal distances (N, H), obstacle distances
    (N, H), the plan (H, M, 3) and the perturbations (N, H, M, 3)."""
    coll = 1.0 / jnp.maximum(dist - c.safety_margin, c.epsilon)
    viol = jnp.sum(jnp.maximum(spec.l_min - arcs, 0.0) + jnp.maximum(arcs - spec.l_max, 0.0), axis=(-2, -1))
    running = (jnp.arange(c.horizon) < c.horizon - 1).astype(arcs.dtype)  # x^1 .. x^{H-1}
    terminal = 1.0 - running  # x^H
    if c.goal_reach:
        c_goal = jnp.sum(c.w_goal * running * jax.lax.cummin(goal_d, axis=1)
                         + c.w_goal_terminal * terminal * goal_d, axis=1)
    else:
        c_goal = jnp.sum(goal_d * (c.w_goal * running + c.w_goal_terminal * terminal), axis=1)
    c_coll = jnp.sum(coll * (c.w_coll * running + c.w_coll_terminal * terminal), axis=1)
    c_state = c.w_state * jnp.sum(viol * running, axis=1)
    c_pert = c.w_perturbation * jnp.sum(nominal[None] * eps, axis=(1, 2, 3)) / c.covariance
    return c_goal, c_coll, c_state, c_pert


def track_progress(c: MPPIConfig, state: MPPIState, goal_now) -> tuple[jnp.ndarray, jnp.ndarray]:
    """The best goal distance so far and the steps without progress, after the current state's."""
    progressed = goal_now < state.best_goal - c.progress
    best_goal = jnp.where(progressed, goal_now, state.best_goal)
    stalled = jnp.where(progressed, 0, state.stalled + 1).astype(jnp.int32)
    return best_goal, stalled


def execute(config, shape, arc, updated, raw, u, total, dist, points, mask, model):
    """The executed action (M, 3), its checked clearance, the safety filter's choice and the next
    warm start: the plan's first control, or with a safety filter its checked candidate."""
    c, spec = config.mppi, shape.spec
    if config.safety is None:
        action = limit_to_state_bounds(arc, updated[0], c.dt, spec)
        return action, jnp.asarray(jnp.nan, arc.dtype), jnp.asarray(0), raw
    check = functools.partial(step_clearance, c.dt, config.safety.substeps, config.broad_phase, shape, arc,
                              points=points, mask=mask, model=model)
    return filtered_action(config.safety, check, spec, arc, c.dt, c.safety_margin, updated, raw, u,
                           jnp.argmin(total), jnp.argmax(dist[:, 0]))


class Iteration(NamedTuple):
    """One update of the plan (:func:`iterate`): the bounded samples (N, H, M, 3), the rollout
    states' predicted obstacle distances (N, H), the weighted cost terms (goal, collision, state,
    perturbation) and their total (N,) each, the weights (N,) and temperature, and the plan after
    the update (``raw``, kept as the warm start, and its bounded form ``updated``, (H, M, 3) each)."""

    bounded: jnp.ndarray
    dist: jnp.ndarray
    terms: tuple
    total: jnp.ndarray
    weights: jnp.ndarray
    temperature: jnp.ndarray
    raw: jnp.ndarray
    updated: jnp.ndarray


def iterate(spec: RobotSpec, config, shape, nominal, key, stalled, arc, goal, points, mask, model, guide) -> Iteration:
    """Sample around the plan ``nominal`` (H, M, 3), roll out, cost, weight and update it (module
    docstring); ``stalled``: the steps without progress, for the temperature stage."""
    c = config.mppi
    eps = sample_noise(config.sampling, c.covariance, c.samples, key, nominal.shape, nominal.dtype)
    perturbed = nominal[None] + eps  # the unbounded samples (N, H, M, 3)
    u = bounded_controls(config.sampling, c.control_bound, perturbed)
    arcs = arc[None, None] + c.dt * jnp.cumsum(u, axis=1)  # x^1 .. x^H
    # Materialised once, so every consumer reads the same frames: XLA otherwise recomputes parts of the
    # chain inside some consumers, with a rounding that can depend on the number of CPU threads.
    frames = jax.lax.optimization_barrier(forward_kinematics(arcs, spec))  # (N, H, M + 1, 4, 4)
    goal_d = goal_distance(frames[..., -1, :, :], goal, guide)  # (N, H)
    dist = state_distances(config, shape, arc, arcs, frames, u[:, 0], points, mask, model)
    terms = cost_terms(c, spec, arcs, goal_d, dist, nominal, eps)
    total = terms[0] + terms[1] + terms[2] + terms[3]
    lo, hi = jnp.min(total), jnp.max(total)
    spread = hi - lo
    norm = jnp.where(spread > 0, (total - lo) / jnp.where(spread > 0, spread, 1.0), 0.0)
    temperature = config.temperature.choose(norm, stalled)
    w = jnp.exp(-norm / temperature)
    w = w / jnp.sum(w)
    raw, updated = update_plan(config.sampling, c.control_bound, c.alpha_u, nominal, perturbed, u, w)
    return Iteration(u, dist, terms, total, w, temperature, raw, updated)


def first_plan(spec: RobotSpec, config, shape, state: MPPIState, arc, goal, points, mask, model, guide):
    """The plan and key for a step: at a step with no goal distance tracked yet (the first, and
    the first after a route is planned or ends), the plan updated ``first_iterations`` - 1 times
    from ``arc`` before the step's own update; the state's otherwise."""
    if config.mppi.first_iterations == 1:
        return state.nominal, state.key

    def once(_, carry):
        nominal, key = carry
        key, k_noise = jax.random.split(key)
        return iterate(spec, config, shape, nominal, k_noise, state.stalled, arc, goal, points, mask, model,
                       guide).raw, key

    def refined():
        return jax.lax.fori_loop(0, config.mppi.first_iterations - 1, once, (state.nominal, state.key))

    return jax.lax.cond(jnp.isinf(state.best_goal), refined, lambda: (state.nominal, state.key))


@functools.partial(jax.jit, static_argnums=(0, 1))
def mppi_step(spec: RobotSpec, config, shape, state: MPPIState, arc, goal, points, mask, model=None, guide=None):
    """One MPPI step (``first_iterations`` updates where no goal distance is tracked yet): a pure
    function, jitted with ``spec`` and the composed ``config`` (``ncedf.controller.ControllerConfig``)
    static; the representation is a pytree argument.

    Args:
      shape: a :class:`ncedf.shapes.Shape`.  state: :class:`MPPIState`.
      arc: (M, 3) current arc lengths, m.  goal: (3,) position or (4, 4) pose.
      points: (max_points, 3) obstacle cloud, m; mask: (max_points,) bool, True = real point, or
        (M, max_points) for the points each link counts (``ncedf.mount``).
      model: the fitted obstacle model (``ncedf.convex.Polytopes`` or ``ncedf.grid_model.GridFit``), or None.
      guide: the guide's field (``ncedf.guide``), or None for the straight goal distance.
    Returns:
      action (M, 3) m/s, the next :class:`MPPIState`, and an :class:`MPPIInfo`.
    """
    c = config.mppi
    nominal, key = first_plan(spec, config, shape, state, arc, goal, points, mask, model, guide)
    key, k_noise = jax.random.split(key)
    best_goal, stalled = track_progress(c, state, goal_distance(forward_kinematics(arc, spec)[-1], goal, guide))
    it = iterate(spec, config, shape, nominal, k_noise, stalled, arc, goal, points, mask, model, guide)
    raw, updated, dist, total = it.raw, it.updated, it.dist, it.total
    c_goal, c_coll, c_state, c_pert = it.terms
    action, clearance, choice, raw = execute(config, shape, arc, updated, raw, it.bounded, total, dist, points,
                                             mask, model)
    next_nominal = jnp.concatenate([raw[1:], raw[-1:]], axis=0)

    best = jnp.argmin(total)
    plan_arcs = jnp.concatenate([arc[None], arc[None] + c.dt * jnp.cumsum(updated, axis=0)], axis=0)
    info = MPPIInfo(
        plan=forward_kinematics(plan_arcs, spec)[:, -1, :3, 3], predicted_min_distance=jnp.min(dist[best]),
        current_min_distance=shape.min_distance(points, arc, mask), cost_goal=c_goal[best],
        cost_coll=c_coll[best], cost_state=c_state[best], cost_perturbation=c_pert[best], cost_min=jnp.min(total),
        cost_max=jnp.max(total), ess=1.0 / jnp.sum(it.weights * it.weights), selected=best,
        rollout_min_distance=dist, temperature=it.temperature, action_clearance=clearance, action_choice=choice)
    return action, MPPIState(next_nominal, key, best_goal, stalled), info
