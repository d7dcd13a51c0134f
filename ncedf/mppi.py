"""MPPI controller for a multi-link continuum robot (paper Sec. V).

Dynamics (paper eq. 3) on the arc lengths: ``x' = x + u dt``. Two ways to
sample control rates that keep each link's three rates summing to zero (the
backbone is inextensible), ``MPPIConfig.sampling``:

* ``"project"`` (default): three rates are sampled, projected to zero sum and
  scaled per link so that no rate exceeds the bound (scaling keeps the zero
  sum; element-wise clipping would not);
* ``"release"`` (the authors' release): two free rates per link are sampled
  and clipped to the bound, the third is minus their sum (so it reaches twice
  the bound).

Noise is white over the horizon, or with ``noise_smoothing`` beta > 0 a
stationary first-order low-pass sequence ``e_k = beta e_{k-1} + sqrt(1 - beta^2) n_k``
(same per-step variance).

Costs (paper Sec. V-B), over the rollout states ``x^1 .. x^H`` of each sample
``j`` (the paper sums ``k = 0 .. H-1``; the ``k = 0`` term is the current state,
the same for every sample, so it cannot change the min-max normalised weights
and is left out; the terminal state ``x^H`` enters only through the release's
terminal weights, 0 by default):

* goal: ``w_goal * ||T_ee(x^k) - T_G||_F`` for a pose goal (4, 4), or
  ``w_goal * ||p_ee(x^k) - p_G||`` for a position goal (3,). The goal kind is
  decided by the goal's shape at trace time (two compiled variants).
* collision: ``w_coll / max(min_p Gamma(p, x^k) - delta_s, epsilon)``.
* state: ``w_state * sum over links and chambers of (l_min - l)_+ + (l - l_max)_+``.
* optional (release): terminal goal / collision weights at ``x^H``, and a
  control-perturbation cost ``w_perturbation * sum_k U_k . eps_k / sigma^2``.
* ``goal_reach``: the running goal term of state ``x^k`` is
  ``w_goal * min_{j <= k} d(x^j)`` (the terminal term keeps ``d(x^H)``). An
  episode ends when the goal is first reached, so a rollout that reaches it
  and then drifts (its noise goes on after the reach) is not charged for the
  drift; without it, the drift of the later states blurs the ranking of the
  first controls near the goal and the robot slows down there.

Update: ``C~ = (C - min C) / (max C - min C)``, ``w = exp(-C~ / lambda)``,
``U <- (1 - alpha_u) U + alpha_u sum_j w_j u^j / sum_j w_j``; the first control is
executed, the plan is shifted by one step (the last control repeated, or zero).
The samples ``u^j`` are bounded (clipped or scaled, ``sampling``), so their
mean lies strictly inside the bound even when every good sample saturates it:
a plan at the bound is pulled back inside at every step. With
``update_unclipped`` the plan is ``U <- (1 - alpha_u) U + alpha_u sum_j w_j
(U + eps^j)``, kept within ``+-NOMINAL_SLACK * control_bound``, and bounded
only when rolled out and executed, so a saturated plan stays saturated (the
robot moves at its top rates when that is best).
With ``target_ess`` set, lambda is not fixed: it is the smallest of a
logarithmic grid (``TEMPERATURE_GRID``) whose weights have an effective sample
size ``1 / sum w^2`` of at least ``target_ess * N`` and ``MIN_ESS`` (so the
update averages several samples instead of collapsing to one).

Stall escape (``stall_steps`` > 0, with ``target_ess``): the state keeps the
smallest goal distance of the current state so far and the steps since it last
fell by ``stall_progress``; after more than ``stall_steps`` such steps the
effective-sample-size target is ``stall_ess`` instead of ``target_ess`` (sharper
weights, larger steps) until the goal distance falls again. The phase of
fast progress, where the robot passes obstacles, keeps ``target_ess``.

Safety check (``safety_check``): before it is executed, the action is checked
against the current cloud with the representation at ``check_substeps`` states
evenly spaced over the step (``x + s/S u dt``, s = 1..S, so a thin wall crossed
within one step is seen). Candidates, in order of preference: the MPPI action,
the lowest-cost sample's first control, the first control of the sample
farthest from the cloud after one step, the MPPI action scaled by
``CHECK_SCALES``, and no motion. The first candidate whose predicted clearance
over the step is at least ``safety_margin + check_margin`` is executed; if none
is, the one with the largest clearance. The fallbacks are evaluated only when
the MPPI action fails the check. Each candidate's clearance comes from the
broad phase (or brute force) on that candidate's own states.
With ``sweep_first`` each rollout's first state is scored by that same
clearance of its first control over the step (the least over the
``check_substeps`` states; the broad phase picks the points for all samples
at once, as for the rollouts): a sample whose step sweeps a link through an
obstacle and out again within ``dt`` looks safe at its end state, so the
update would follow it and the check would then refuse it. That score is
also the first column of ``MPPIInfo.rollout_min_distance`` and decides the
check's "farthest sample".
With ``follow_executed`` the next step is warm-started from the executed
candidate's controls (the lowest-cost or farthest sample's, the plan scaled,
or zeros) instead of the plan the check refused. A refused plan otherwise
stays the warm start, and when its first control is saturated towards an
obstacle every sample around it crosses the obstacle too: their collision
costs all sit at the ceiling ``w_coll / epsilon``, the goal cost alone ranks
them, and the update keeps the plan, so the robot holds still for as long as
the obstacle stays (the dynamic spheres, random-goal environment 88: 196
steps).

Surface model (``fill_edge`` > 0): rollouts and the safety check score the
observed cloud together with points filled in between neighbours up to
``fill_edge`` apart (``ncedf.cloud``), so that the robot does not slide into a
sparsely sampled surface between its points; ``MPPIInfo.current_min_distance``
stays the distance to the observed points.

Convex model (``convex_link`` > 0): the cloud's rows that did not move since
the previous step and those that did are clustered apart (static clusters whose
bounding boxes lie within ``convex_link`` merge, so a sparsely sampled box stays
whole) and each cluster is closed as a convex polytope (``ncedf.convex``: exact
for boxes sampled on their faces, holes included; a cluster on a sphere is its
ball); every rollout state's and safety-check state's predicted distance is the smaller of the
representation's and a lower bound of the robot body's clearance to the
polytopes, each moved at the mean velocity of its points (their displacement
since the previous cloud over dt; zero at the first step) to the state's time.
:meth:`MPPI.step` fits the polytopes (numpy, about 0.5 ms per step for 500
points: a static group of points is fitted once) and passes them to the step.
With ``hold_time`` > 0 a rollout's last state is also scored as if the robot
held it for ``hold_time`` more seconds: its clearance to the moving polytopes
moved to ``HOLD_SAMPLES`` times evenly spaced over ``(H dt, H dt + hold_time]``
(a static one's is that at ``H dt``, already scored); a moving one that would run
into the held state makes it costly, so the robot does not end its plan, or
wait, in the path of an obstacle that the horizon sees only approaching, and it
dodges behind the obstacle rather than ahead of it.

Route (``route_after`` > 0, with ``convex_link``): MPPI is local, and where
the way to a position goal first leads away from it (a goal right behind a
box) it stalls. When the steps without progress (the stall escape's counter,
kept at every step) reach ``route_after`` + 1, and again every ``route_after``
steps while they grow, :meth:`MPPI.step` plans a route from the current state
round the static polytopes (``ncedf.route``: a roadmap over arc lengths; the
moving clusters are left out). Where the roadmap holds none, nothing else
changes: the stall escape's sharpened weights go on. Else it executes it:
each step moves to the farthest route state within one step's bound (or
towards the next, at the bound), if that move passes the safety check
(:func:`step_clearance`, which sees the moving polytopes); else it holds if
holding passes, else it takes MPPI's own checked action. MPPI keeps planning
underneath and takes over at the route's end. At most ``ROUTE_TRIES`` routes
per episode.

Moving obstacles (``predict_motion``): the controller keeps the previous
cloud; a point's velocity is its displacement since the previous step over dt
(clouds whose row ``i`` is the same physical point at every step, as the
scenarios observe them; zero at the first step or for a row that was padding).
Rollout state ``x^k`` is then scored against the cloud moved by ``k dt`` times
the velocities, and the safety check's substep ``s`` against the cloud moved by
``s/S dt``.

The step is a pure function, :func:`mppi_step` (jitted with the robot and the
settings static, so every controller built with them shares its compiled
programs). :class:`MPPI` is a thin validating shell: :meth:`MPPI.step` checks its
inputs, pads the obstacle cloud to ``max_points`` with a mask, and calls it, so
new states, goals and obstacle clouds (of any size up to the capacity) reuse one
compiled program per goal kind.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ncedf.broad_phase import SELECTIONS, rollout_min_distances_broad, rollout_min_distances_brute
from ncedf.cloud import fill_weights, interpolate
from ncedf.convex import fit_polytopes, robot_clearance, static_rows
from ncedf.precision import MATMUL
from ncedf.robot import RobotSpec, forward_kinematics, validate_state
from ncedf.route import RouteConfig, plan_route, tips
from ncedf.shapes import Shape

#: Ways to sample zero-sum control rates (``MPPIConfig.sampling``).
SAMPLING = ("project", "release")
#: Candidate temperatures when ``MPPIConfig.target_ess`` is set (on costs normalised to [0, 1]).
TEMPERATURE_GRID = tuple(float(x) for x in np.logspace(-4, 1, 64))
#: Least effective sample size asked for with ``MPPIConfig.target_ess`` (few rollouts would
#: otherwise execute one noisy sample), samples.
MIN_ESS = 4.0
#: Bound of the unclipped plan (``MPPIConfig.update_unclipped``), in units of ``control_bound``.
NOMINAL_SLACK = 2.0
#: Times at which a rollout's held last state is scored (``MPPIConfig.hold_time``).
HOLD_SAMPLES = 4
#: Scales of the MPPI action among the safety check's candidates (before "no motion").
CHECK_SCALES = (0.5, 0.25)
#: Route states :class:`MPPIState` holds (a longer route is thinned evenly).
ROUTE_CAPACITY = 1024
#: Routes planned per episode at most.
ROUTE_TRIES = 3
#: Folded into the state's key for a route's samples.
ROUTE_SALT = 0x726F7574


@dataclasses.dataclass(frozen=True)
class MPPIConfig:
    """MPPI settings; defaults are the paper's (Sec. VI-A).

    Attributes:
      samples: rollouts N.  horizon: H steps.
      covariance: sampling covariance sigma^2 (Sigma = sigma^2 I), (m/s)^2.
      temperature: lambda.  alpha_u: smoothing of the update, in (0, 1].
      w_goal, w_coll, w_state: cost weights.
      w_goal_terminal, w_coll_terminal: terminal weights at x^H (release: 22, 1.1).
      w_perturbation: control-perturbation cost weight (release: 0.1).
      noise_clip: clip each noise component to +-noise_clip (release: 0.5); None = off.
      safety_margin: delta_s, m.  epsilon: floor of the collision-cost denominator, m.
      control_bound: largest |rate|, m/s.  dt: step, s.
      max_points: obstacle-cloud capacity (clouds are padded to it with a mask).
      broad_phase: evaluate the representation on broad-phase pairs only
        (``ncedf.broad_phase``); False = brute force over every point.
      k1, k2, capsule_segments: broad-phase sizes (see ``ncedf.broad_phase``):
        K1 candidate points per (horizon step, link) of selection ``mean``, K2
        (link, point) pairs evaluated per rollout state, sub-arc capsules per
        link. K2 = 12 keeps >= 99.9% of the rollout minima equal to brute force
        at the paper setting (``bench/mppi_step.py``); the network cost grows with it.
      selection: the broad phase's candidates: "mean" (per horizon step around
        the rollouts' average: fast, over-estimates distances of rollouts far
        from it) or "state" (per rollout state from groups of the cloud; see
        ``ncedf.broad_phase`` and ``bench/broad_phase.py``).
      groups, group_size: selection "state": (link, group) pairs kept per
        rollout state, and points per group.
      shift_fill: "last" (repeat the last control) or "zero" after the shift.
      limit_action: scale the executed action so the next state stays within
        the arc-length limits (rollouts keep the soft state cost).
      sampling: "project" (three rates projected to zero sum, scaled to the
        bound) or "release" (two free rates clipped to the bound, the third
        minus their sum); see the module docstring.
      noise_smoothing: beta in [0, 1) of the low-pass noise over the horizon
        (0 = white noise).
      target_ess: None = fixed ``temperature``; else in (0, 1]: lambda is
        chosen per step for an effective sample size >= target_ess * samples.
      safety_check: check the executed action against the cloud (module docstring).
      check_substeps: states checked over the step.  check_margin: clearance
        above ``safety_margin`` the check demands, m.
      predict_motion: move the cloud at the velocities estimated from the
        previous step's cloud (module docstring).
      fill_edge: 0 = score the observed cloud as it is; > 0 = score a surface
        model of it with the points between neighbours up to this far apart
        (``ncedf.cloud``), m.
      stall_steps: 0 = off; else the steps without progress after which the
        ESS target is ``stall_ess`` (module docstring; needs ``target_ess``).
      stall_ess: the ESS target of a stalled robot, in (0, 1].
      stall_progress: the fall of the best goal distance that counts as
        progress, m (or Frobenius units for a pose goal).
      goal_reach: charge each running state the closest goal distance of
        its rollout so far instead of its own (module docstring).
      update_unclipped: update the plan with the weighted mean of the
        unclipped samples and bound it only when rolled out and executed
        (module docstring).
      convex_link: 0 = off; > 0 = also score the robot's clearance to convex
        polytopes of the cloud's clusters (static and moving points apart) at
        this single-linkage distance, m (``ncedf.convex``; module docstring).
      hold_time: 0 = off; > 0 = also score each rollout's last state held this
        much longer against the moving polytopes, s (module docstring; needs
        ``convex_link``).
      sweep_first: score each rollout's first state by the clearance over its
        step, as the safety check sees it (module docstring).
      follow_executed: when the safety check executes a fallback, warm-start
        the next step from the fallback's controls instead of the refused plan
        (module docstring; needs ``safety_check``).
      route_after: 0 = off; else the steps without progress after which
        :meth:`MPPI.step` plans a route round the static polytopes and executes
        it (module docstring; needs ``convex_link``).
      route: the route planner's settings (``ncedf.route.RouteConfig``, or its
        fields as a dict, as a recording's metadata holds them).
    """

    samples: int = 800
    horizon: int = 20
    covariance: float = 0.05
    temperature: float = 0.02
    alpha_u: float = 1.0
    w_goal: float = 12.0
    w_coll: float = 1.1
    w_state: float = 50.0
    w_goal_terminal: float = 0.0
    w_coll_terminal: float = 0.0
    w_perturbation: float = 0.0
    noise_clip: float | None = None
    safety_margin: float = 0.05
    epsilon: float = 0.01
    control_bound: float = 0.3
    dt: float = 0.05
    max_points: int = 512
    broad_phase: bool = True
    k1: int = 128
    k2: int = 12
    capsule_segments: int = 2
    selection: str = "mean"
    groups: int = 32
    group_size: int = 16
    shift_fill: str = "last"
    limit_action: bool = True
    sampling: str = "project"
    noise_smoothing: float = 0.0
    target_ess: float | None = None
    safety_check: bool = False
    check_substeps: int = 4
    check_margin: float = 0.0
    predict_motion: bool = False
    fill_edge: float = 0.0
    stall_steps: int = 0
    stall_ess: float = 0.01
    stall_progress: float = 0.05
    goal_reach: bool = False
    update_unclipped: bool = False
    convex_link: float = 0.0
    hold_time: float = 0.0
    sweep_first: bool = False
    follow_executed: bool = False
    route_after: int = 0
    route: RouteConfig = RouteConfig()

    def __post_init__(self):
        def num(name):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
                raise ValueError(f"MPPIConfig.{name} must be a number, got {value!r}")
            if not math.isfinite(value):
                raise ValueError(f"MPPIConfig.{name} must be finite, got {value!r}")
            return value

        for name in ("samples", "horizon", "max_points", "k1", "k2", "capsule_segments", "groups", "group_size",
                     "check_substeps"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
                raise ValueError(f"MPPIConfig.{name} must be an integer, got {value!r}")
            if value < 1:
                raise ValueError(f"MPPIConfig.{name} must be >= 1, got {value}")
        for name in ("covariance", "temperature", "control_bound", "dt", "epsilon"):
            if num(name) <= 0:
                raise ValueError(f"MPPIConfig.{name} must be > 0, got {getattr(self, name)}")
        for name in ("w_goal", "w_coll", "w_state", "w_goal_terminal", "w_coll_terminal", "w_perturbation", "safety_margin",
                     "check_margin", "fill_edge", "convex_link", "hold_time"):
            if num(name) < 0:
                raise ValueError(f"MPPIConfig.{name} must be >= 0, got {getattr(self, name)}")
        if not 0 < num("alpha_u") <= 1:
            raise ValueError(f"MPPIConfig.alpha_u must be in (0, 1], got {self.alpha_u}")
        if self.noise_clip is not None and num("noise_clip") <= 0:
            raise ValueError(f"MPPIConfig.noise_clip must be > 0 or None, got {self.noise_clip}")
        if not 0 <= num("noise_smoothing") < 1:
            raise ValueError(f"MPPIConfig.noise_smoothing must be in [0, 1), got {self.noise_smoothing}")
        if self.target_ess is not None and not 0 < num("target_ess") <= 1:
            raise ValueError(f"MPPIConfig.target_ess must be in (0, 1] or None, got {self.target_ess}")
        if isinstance(self.stall_steps, bool) or not isinstance(self.stall_steps, (int, np.integer)):
            raise ValueError(f"MPPIConfig.stall_steps must be an integer, got {self.stall_steps!r}")
        if self.stall_steps < 0:
            raise ValueError(f"MPPIConfig.stall_steps must be >= 0, got {self.stall_steps}")
        if not 0 < num("stall_ess") <= 1:
            raise ValueError(f"MPPIConfig.stall_ess must be in (0, 1], got {self.stall_ess}")
        if num("stall_progress") <= 0:
            raise ValueError(f"MPPIConfig.stall_progress must be > 0, got {self.stall_progress}")
        if isinstance(self.route_after, bool) or not isinstance(self.route_after, (int, np.integer)):
            raise ValueError(f"MPPIConfig.route_after must be an integer, got {self.route_after!r}")
        if self.route_after < 0:
            raise ValueError(f"MPPIConfig.route_after must be >= 0, got {self.route_after}")
        if self.route_after and not self.convex_link:
            raise ValueError("MPPIConfig.route_after needs convex_link (the route avoids the polytopes)")
        if isinstance(self.route, dict):  # read back from a recording's metadata
            object.__setattr__(self, "route", RouteConfig(**self.route))
        if not isinstance(self.route, RouteConfig):
            raise ValueError(f"MPPIConfig.route must be a RouteConfig, got {type(self.route).__name__}")
        if self.stall_steps and self.target_ess is None:
            raise ValueError("MPPIConfig.stall_steps needs target_ess (the stall escape changes the ESS target)")
        if self.hold_time and not self.convex_link:
            raise ValueError("MPPIConfig.hold_time needs convex_link (the held state is scored against the polytopes)")
        if self.selection not in SELECTIONS:
            raise ValueError(f"MPPIConfig.selection must be one of {', '.join(SELECTIONS)}, got {self.selection!r}")
        if self.sampling not in SAMPLING:
            raise ValueError(f"MPPIConfig.sampling must be one of {', '.join(SAMPLING)}, got {self.sampling!r}")
        for name in ("broad_phase", "limit_action", "safety_check", "predict_motion", "goal_reach", "update_unclipped",
                     "sweep_first", "follow_executed"):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f"MPPIConfig.{name} must be a bool, got {getattr(self, name)!r}")
        if self.follow_executed and not self.safety_check:
            raise ValueError("MPPIConfig.follow_executed needs safety_check (it follows the check's fallback)")
        if self.shift_fill not in ("last", "zero"):
            raise ValueError(f"MPPIConfig.shift_fill must be 'last' or 'zero', got {self.shift_fill!r}")


class MPPIState(NamedTuple):
    """Controller state (a pytree): nominal controls (H, M, 3) m/s (with ``update_unclipped``
    the unbounded plan, within +-NOMINAL_SLACK * control_bound), a PRNG key, the
    previous step's cloud (max_points, 3) m with its mask (max_points,) (all False at first),
    the smallest goal distance of the current state so far (scalar, +inf at first), the
    steps since it last fell by ``stall_progress`` (scalar int32), and a route: its states
    (ROUTE_CAPACITY, M, 3) m, the index of the last one reached and their count (scalar
    int32; no route: 0) and the routes planned so far (scalar int32)."""

    nominal: jnp.ndarray
    key: jnp.ndarray
    previous: jnp.ndarray
    previous_mask: jnp.ndarray
    best_goal: jnp.ndarray
    stalled: jnp.ndarray
    route: jnp.ndarray
    route_at: jnp.ndarray
    route_end: jnp.ndarray
    routes: jnp.ndarray


class MPPIInfo(NamedTuple):
    """Diagnostics of one step (a pytree of arrays).

    plan: (H + 1, 3) end-effector positions along the updated plan, from the
      current state, m.
    predicted_min_distance: min over x^1..x^H of the selected rollout's
      predicted min distance (selected = the lowest-cost sample), m.
    current_min_distance: predicted min distance from the current state to the
      observed cloud (without fill points), m.
    cost_goal, cost_coll, cost_state, cost_perturbation: the selected rollout's
      weighted cost terms.
    cost_min, cost_max: the range of total costs over the samples.
    ess: effective sample size of the weights, ``1 / sum w^2`` (w normalised).
    selected: index of the selected rollout.
    rollout_min_distance: (N, H) predicted min distance of every rollout state.
    temperature: the lambda used (``temperature`` or the one chosen for ``target_ess``).
    action_clearance: predicted clearance over the executed step (the safety
      check's; NaN without it), m.
    action_choice: the executed safety-check candidate (0 = the MPPI action;
      see the module docstring; 0 without the check).
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


def project_controls(u: jnp.ndarray, bound: float) -> jnp.ndarray:
    """Make each link's three rates sum to zero, then scale so ``max |u| <= bound``.

    Args:
      u: (..., 3) rates per link, m/s.
    """
    u = u - jnp.mean(u, axis=-1, keepdims=True)
    peak = jnp.max(jnp.abs(u), axis=-1, keepdims=True)
    return u * jnp.minimum(1.0, bound / jnp.maximum(peak, 1e-30))


def release_controls(free: jnp.ndarray, bound: float) -> jnp.ndarray:
    """The release's zero-sum rates: two free rates clipped to ``+-bound``, the third minus their sum.

    Args:
      free: (..., 2) rates per link, m/s.
    Returns:
      (..., 3) rates, m/s (the third within ``+-2 bound``).
    """
    free = jnp.clip(free, -bound, bound)
    return jnp.concatenate([free, -jnp.sum(free, axis=-1, keepdims=True)], axis=-1)


def smoothing_matrix(horizon: int, beta: float) -> np.ndarray:
    """(H, H) lower-triangular L with ``e = L n`` the stationary low-pass sequence
    ``e_0 = n_0``, ``e_k = beta e_{k-1} + sqrt(1 - beta^2) n_k`` (unit variance per step for white n)."""
    k = np.arange(horizon)
    lag = k[:, None] - k[None, :]
    gain = np.where(k[None, :] == 0, 1.0, math.sqrt(1.0 - beta * beta))
    return np.where(lag >= 0, beta ** np.maximum(lag, 0) * gain, 0.0).astype(np.float32)


def sample_noise(config: MPPIConfig, key, dims: tuple[int, ...], dtype) -> jnp.ndarray:
    """Perturbations (N, H, M, 3) m/s: Gaussian with variance ``covariance``, low-pass over the
    horizon if ``noise_smoothing`` > 0, clipped to ``noise_clip``; with release sampling the third
    rate of each link carries no noise (it is derived)."""
    eps = math.sqrt(config.covariance) * jax.random.normal(key, (config.samples,) + dims, dtype)
    if config.noise_smoothing > 0:
        eps = jnp.einsum("ts,nsmc->ntmc", smoothing_matrix(dims[0], config.noise_smoothing), eps,
                         precision=MATMUL)
    if config.noise_clip is not None:
        eps = jnp.clip(eps, -config.noise_clip, config.noise_clip)
    if config.sampling == "release":
        eps = eps.at[..., 2].set(0.0)
    return eps


def bounded_controls(config: MPPIConfig, raw: jnp.ndarray) -> jnp.ndarray:
    """Zero-sum rates within the bound (..., M, 3) from unbounded ones (``config.sampling``; with
    release sampling the third raw rate is ignored)."""
    if config.sampling == "release":
        return release_controls(raw[..., :2], config.control_bound)
    return project_controls(raw, config.control_bound)


def temperature_for_ess(norm: jnp.ndarray, target) -> jnp.ndarray:
    """The smallest lambda of ``TEMPERATURE_GRID`` whose weights ``exp(-norm / lambda)`` have an
    effective sample size >= ``max(target * N, MIN_ESS)`` (at most N; the largest lambda if none has).

    Args:
      norm: (N,) costs normalised to [0, 1].  target: scalar in (0, 1] (may be traced).
    """
    grid = jnp.asarray(TEMPERATURE_GRID, norm.dtype)
    w = jnp.exp(-norm[None] / grid[:, None])  # (G, N); the minimum keeps weight 1
    ess = jnp.sum(w, axis=1) ** 2 / jnp.sum(w * w, axis=1)
    n = norm.shape[0]
    ok = ess >= jnp.minimum(jnp.maximum(target * n, MIN_ESS), n)
    return jnp.where(jnp.any(ok), grid[jnp.argmax(ok)], grid[-1])


def step_clearance(config: MPPIConfig, shape, arc: jnp.ndarray, actions: jnp.ndarray, points, mask,
                   velocity=None, polytopes=None, shared: bool = False) -> jnp.ndarray:
    """Predicted clearance over one step for each action: min over the states
    ``arc + (s / S) u dt``, s = 1..S (``config.check_substeps``, ``config.dt``), of the
    representation's min distance to the cloud (moved by ``(s / S) dt velocity`` when
    velocities are given), by the broad phase or brute force as the rollouts are
    (``config.broad_phase``), and of the clearance to the polytopes if given.

    Args:
      arc: (M, 3) m.  actions: (C, M, 3) m/s.  points: (P, 3) m; mask: (P,) bool.
      velocity: (P, 3) m/s or None.  polytopes: ``ncedf.convex.Polytopes`` or None.
      shared: False = the broad phase picks points for each action apart (the
        safety check's few candidates, which can move apart); True = for all
        actions at once, as for the rollouts (many actions from one state).
    Returns:
      (C,) m (+inf for an empty cloud).
    """
    frac = jnp.arange(1, config.check_substeps + 1, dtype=arc.dtype) / config.check_substeps
    states = arc + config.dt * frac[None, :, None, None] * actions[:, None]  # (C, S, M, 3)
    if velocity is not None:
        points = points + config.dt * frac[:, None, None] * velocity  # (S, P, 3)
    if shared:
        clearance = jnp.min(rollout_min_distances(config, shape, states, points, mask), axis=1)
    else:
        # One candidate at a time: the broad phase picks its points near the mean of the states it
        # is given, and the candidates can move in opposite directions.
        one = lambda s: jnp.min(rollout_min_distances(config, shape, s[None], points, mask))  # noqa: E731
        clearance = jax.vmap(one)(states)
    if polytopes is not None:
        frames = forward_kinematics(states, shape.spec)
        ahead = robot_clearance(states, frames, shape.spec, polytopes, config.dt * frac)  # (C, S)
        clearance = jnp.minimum(clearance, jnp.min(ahead, axis=1))
    return clearance


def held_clearance(spec: RobotSpec, polytopes, arcs: jnp.ndarray, frames: jnp.ndarray, start, hold_time: float):
    """(B...,) the robot's clearance to the moving polytopes while it holds still: the least
    of ``ncedf.convex.robot_clearance`` at ``HOLD_SAMPLES`` times evenly spaced over
    ``(start, start + hold_time]``, m (+inf without moving polytopes; a static one's
    clearance is that at ``start`` throughout, so it is left out).

    Args:
      arcs: (B..., M, 3) m.  frames: (B..., M + 1, 4, 4) their forward kinematics.
      start: s (scalar).  hold_time: s.
    """
    times = start + hold_time * jnp.arange(1, HOLD_SAMPLES + 1, dtype=arcs.dtype) / HOLD_SAMPLES  # (K,)
    moving = polytopes._replace(present=polytopes.present & jnp.any(polytopes.velocity != 0, axis=-1))
    clearance = robot_clearance(arcs[..., None, :, :], frames[..., None, :, :, :], spec, moving, times)
    return jnp.min(clearance, axis=-1)


def cloud_velocity(points, mask, previous, previous_mask, dt: float) -> jnp.ndarray:
    """(P, 3) m/s: each row's displacement since the previous cloud over dt; zero where
    either cloud has padding."""
    both = (mask & previous_mask)[:, None]
    return jnp.where(both, (points - previous) / dt, 0.0)


def limit_to_state_bounds(arc: jnp.ndarray, u: jnp.ndarray, dt: float, spec: RobotSpec) -> jnp.ndarray:
    """Scale each link's rate (keeping the zero sum) so ``arc + u dt`` stays in the limits.

    ``arc`` (M, 3) is assumed within the limits; returns u (M, 3) scaled per link
    by the largest factor in [0, 1] that keeps every chamber in [l_min, l_max].
    """
    step = u * dt
    room = jnp.where(step > 0, spec.l_max - arc, arc - spec.l_min)
    room = jnp.maximum(room, 0.0)
    ratio = jnp.where(jnp.abs(step) > 0, room / jnp.maximum(jnp.abs(step), 1e-30), jnp.inf)
    return u * jnp.minimum(1.0, jnp.min(ratio, axis=-1, keepdims=True))


def init_state(spec: RobotSpec, config: MPPIConfig, key) -> MPPIState:
    """Zero nominal controls (paper: the initial reference is zero), the key, no previous cloud,
    no goal distance yet."""
    zero = jnp.asarray(0, jnp.int32)
    return MPPIState(jnp.zeros((config.horizon, spec.n_links, 3), jnp.float32), jnp.asarray(key),
                     jnp.zeros((config.max_points, 3), jnp.float32), jnp.zeros(config.max_points, bool),
                     jnp.asarray(jnp.inf, jnp.float32), zero,
                     jnp.zeros((ROUTE_CAPACITY if config.route_after else 1, spec.n_links, 3), jnp.float32), zero,
                     zero, zero)


def rollout_min_distances(config: MPPIConfig, shape, arcs, points, mask, frames=None):
    """(N, H) min distance per rollout state (N, H, M, 3), by the broad phase or brute force.

    ``points`` is one cloud (P, 3), or (H, P, 3): one per horizon step (moving obstacles).
    """
    if points.ndim == 3:
        frames = forward_kinematics(arcs, shape.spec) if frames is None else frames
        per_step = jax.vmap(lambda a, f, p: rollout_min_distances(config, shape, a[:, None], p, mask, f[:, None]),
                            in_axes=(1, 1, 0))
        return per_step(arcs, frames, points)[..., 0].T
    if config.broad_phase:
        return rollout_min_distances_broad(shape, arcs, points, mask, config.k1, config.k2, config.capsule_segments,
                                           frames, config.selection, config.groups, config.group_size)
    return rollout_min_distances_brute(shape, arcs, points, mask)


def goal_distance(frames_ee: jnp.ndarray, goal: jnp.ndarray) -> jnp.ndarray:
    """Goal cost distance: Frobenius ``||T_ee - T_G||`` for a pose goal (4, 4), else
    ``||p_ee - p_G||`` for a position goal (3,); ``frames_ee`` (..., 4, 4) -> (...,)."""
    if goal.shape == (4, 4):
        return jnp.sqrt(jnp.sum((frames_ee - goal) ** 2, axis=(-2, -1)))
    return jnp.sqrt(jnp.sum((frames_ee[..., :3, 3] - goal) ** 2, axis=-1))


@functools.partial(jax.jit, static_argnums=(0, 1))
def mppi_step(spec: RobotSpec, config: MPPIConfig, shape, state: MPPIState, arc, goal, points, mask,
              polytopes=None):
    """One MPPI iteration: a pure function, jitted with ``spec`` and ``config`` static.

    No validation (see :meth:`MPPI.step` for the validated form). Every
    controller with the same robot, settings and kind of representation shares
    one compiled program per goal kind; the representation is a pytree argument.

    Args:
      shape: a :class:`ncedf.shapes.Shape`.  state: :class:`MPPIState`.
      arc: (M, 3) current arc lengths, m.  goal: (3,) position or (4, 4) pose.
      points: (max_points, 3) obstacle cloud, m; mask: (max_points,) bool, True = real point.
      polytopes: ``ncedf.convex.Polytopes`` of the cloud (used with
        ``convex_link`` > 0), or None.
    Returns:
      action (M, 3) m/s, the next :class:`MPPIState`, and an :class:`MPPIInfo`.
    """
    c = config
    if c.convex_link == 0:
        polytopes = None
    key, k_noise = jax.random.split(state.key)
    nominal = state.nominal
    eps = sample_noise(c, k_noise, nominal.shape, nominal.dtype)
    perturbed = nominal[None] + eps  # the unbounded samples (N, H, M, 3)
    u = bounded_controls(c, perturbed)
    arcs = arc[None, None] + c.dt * jnp.cumsum(u, axis=1)  # x^1 .. x^H

    # Per-state terms.
    # Materialised once, so every consumer reads the same frames: XLA otherwise recomputes parts of the
    # chain inside some consumers, with a rounding that can depend on the number of CPU threads.
    frames = jax.lax.optimization_barrier(forward_kinematics(arcs, spec))  # (N, H, M + 1, 4, 4)
    goal_d = goal_distance(frames[..., -1, :, :], goal)  # (N, H)
    observed, observed_mask = points, mask
    velocity = (cloud_velocity(points, mask, state.previous, state.previous_mask, c.dt) if c.predict_motion
                else None)
    if c.fill_edge > 0:
        parents, weights, offsets, valid = fill_weights(points, mask, c.fill_edge)
        points = jnp.concatenate([points, interpolate(points, parents, weights) + offsets])
        mask = jnp.concatenate([mask, valid])
        if velocity is not None:
            velocity = jnp.concatenate([velocity, interpolate(velocity, parents, weights)])
    ahead = c.dt * jnp.arange(1, c.horizon + 1, dtype=arcs.dtype)  # the times of x^1 .. x^H, s
    if velocity is not None:
        dist = rollout_min_distances(config, shape, arcs, points + ahead[:, None, None] * velocity, mask, frames)
    else:
        dist = rollout_min_distances(config, shape, arcs, points, mask, frames)  # (N, H)
    if polytopes is not None:
        dist = jnp.minimum(dist, robot_clearance(arcs, frames, spec, polytopes, ahead))
    if c.sweep_first:  # x^1 scored over the states of its step, as the safety check scores an action
        swept = step_clearance(c, shape, arc, u[:, 0], points, mask, velocity, polytopes, shared=True)
        dist = dist.at[:, 0].min(swept)
    scored = dist  # (N, H) the distances the collision cost sees
    if polytopes is not None and c.hold_time > 0:
        hold = held_clearance(spec, polytopes, arcs[:, -1], frames[:, -1], ahead[-1], c.hold_time)
        scored = dist.at[:, -1].min(hold)
    coll = 1.0 / jnp.maximum(scored - c.safety_margin, c.epsilon)
    viol = jnp.sum(jnp.maximum(spec.l_min - arcs, 0.0) + jnp.maximum(arcs - spec.l_max, 0.0), axis=(-2, -1))

    running = (jnp.arange(c.horizon) < c.horizon - 1).astype(arcs.dtype)  # x^1 .. x^{H-1}
    terminal = 1.0 - running  # x^H
    if c.goal_reach:  # the running states charged their closest approach so far, x^H its own distance
        c_goal = jnp.sum(c.w_goal * running * jax.lax.cummin(goal_d, axis=1)
                         + c.w_goal_terminal * terminal * goal_d, axis=1)
    else:  # (written as before goal_reach existed: the same float operations, so recordings repeat)
        c_goal = jnp.sum(goal_d * (c.w_goal * running + c.w_goal_terminal * terminal), axis=1)
    c_coll = jnp.sum(coll * (c.w_coll * running + c.w_coll_terminal * terminal), axis=1)
    c_state = c.w_state * jnp.sum(viol * running, axis=1)
    c_pert = c.w_perturbation * jnp.sum(nominal[None] * eps, axis=(1, 2, 3)) / c.covariance
    total = c_goal + c_coll + c_state + c_pert

    lo, hi = jnp.min(total), jnp.max(total)
    spread = hi - lo
    norm = jnp.where(spread > 0, (total - lo) / jnp.where(spread > 0, spread, 1.0), 0.0)
    goal_now = goal_distance(forward_kinematics(arc, spec)[-1], goal)
    progressed = goal_now < state.best_goal - c.stall_progress
    best_goal = jnp.where(progressed, goal_now, state.best_goal)
    stalled = jnp.where(progressed, 0, state.stalled + 1).astype(jnp.int32)
    if c.target_ess is None:
        temperature = jnp.asarray(c.temperature, norm.dtype)
    else:
        target = jnp.where(stalled > c.stall_steps, c.stall_ess, c.target_ess) if c.stall_steps else c.target_ess
        temperature = temperature_for_ess(norm, target)
    w = jnp.exp(-norm / temperature)
    w = w / jnp.sum(w)
    ess = 1.0 / jnp.sum(w * w)
    if c.update_unclipped:
        raw = (1.0 - c.alpha_u) * nominal + c.alpha_u * jnp.einsum("n,nhmc->hmc", w, perturbed, precision=MATMUL)
        raw = jnp.clip(raw, -NOMINAL_SLACK * c.control_bound, NOMINAL_SLACK * c.control_bound)
        updated = bounded_controls(c, raw)
    else:
        raw = updated = (1.0 - c.alpha_u) * nominal + c.alpha_u * jnp.einsum("n,nhmc->hmc", w, u, precision=MATMUL)

    best = jnp.argmin(total)
    action = updated[0]
    clearance, choice = jnp.asarray(jnp.nan, arc.dtype), jnp.asarray(0)
    if c.safety_check:
        safest = jnp.argmax(dist[:, 0])
        # Each candidate's controls over the horizon (H, M, 3); the check judges the first.
        plans = jnp.stack([updated, u[best], u[safest]] + [s * updated for s in CHECK_SCALES]
                          + [jnp.zeros_like(updated)])
        candidates = plans[:, 0]
        if c.limit_action:
            candidates = jax.vmap(lambda a: limit_to_state_bounds(arc, a, c.dt, spec))(candidates)
        needed = c.safety_margin + c.check_margin
        check = functools.partial(step_clearance, c, shape, arc, points=points, mask=mask, velocity=velocity,
                                  polytopes=polytopes)
        # The candidates in order until one passes: the fallbacks are evaluated only when the MPPI
        # action fails, and the program holds one copy of the check (compile time).
        def unchecked(carry):
            i, clear = carry
            return (i < len(candidates)) & ((i == 0) | (clear[i - 1] < needed))

        def check_next(carry):
            i, clear = carry
            return i + 1, clear.at[i].set(check(actions=candidates[i][None])[0])

        clear = jnp.full(len(candidates), -jnp.inf, arc.dtype)
        _, clear = jax.lax.while_loop(unchecked, check_next, (jnp.asarray(0), clear))
        ok = clear >= needed
        choice = jnp.where(jnp.any(ok), jnp.argmax(ok), jnp.argmax(clear))
        action, clearance = candidates[choice], clear[choice]
        if c.follow_executed:  # the executed candidate's plan is the next warm start (the MPPI plan unbounded)
            raw = jnp.where(choice == 0, raw, plans[choice])
    elif c.limit_action:
        action = limit_to_state_bounds(arc, action, c.dt, spec)
    fill = raw[-1:] if c.shift_fill == "last" else jnp.zeros_like(raw[-1:])
    next_nominal = jnp.concatenate([raw[1:], fill], axis=0)

    plan_arcs = jnp.concatenate([arc[None], arc[None] + c.dt * jnp.cumsum(updated, axis=0)], axis=0)
    plan = forward_kinematics(plan_arcs, spec)[:, -1, :3, 3]
    info = MPPIInfo(
        plan=plan,
        predicted_min_distance=jnp.min(dist[best]),
        current_min_distance=shape.min_distance(observed, arc, observed_mask),
        cost_goal=c_goal[best],
        cost_coll=c_coll[best],
        cost_state=c_state[best],
        cost_perturbation=c_pert[best],
        cost_min=lo,
        cost_max=hi,
        ess=ess,
        selected=best,
        rollout_min_distance=dist,
        temperature=temperature,
        action_clearance=clearance,
        action_choice=choice,
    )
    return action, state._replace(nominal=next_nominal, key=key, previous=observed, previous_mask=observed_mask,
                                  best_goal=best_goal, stalled=stalled), info


#: The safety check of a route's moves (jitted apart from ``mppi_step``: compiled only when a route runs).
_check_moves = jax.jit(step_clearance, static_argnums=0, static_argnames="shared")


class MPPI:
    """MPPI for ``spec`` with a shape representation from :func:`ncedf.shapes.make_shape`.

    Use ``state = mppi.init(key)`` then
    ``action, state, info = mppi.step(state, arc, goal, obstacle_points)``.
    """

    def __init__(self, spec: RobotSpec, shape, config: MPPIConfig | None = None):
        if not isinstance(spec, RobotSpec):
            raise ValueError(f"spec must be a RobotSpec, got {type(spec).__name__}")
        config = MPPIConfig() if config is None else config
        if not isinstance(config, MPPIConfig):
            raise ValueError(f"config must be an MPPIConfig, got {type(config).__name__}")
        if not isinstance(shape, Shape):
            raise ValueError(f"shape must be a representation from ncedf.shapes.make_shape, got {shape!r}")
        if shape.spec.n_links != spec.n_links:
            raise ValueError(f"the shape is for {shape.spec.n_links} links, the robot has {spec.n_links}")
        self.spec = spec
        self.shape = shape
        self.config = config

    def init(self, key) -> MPPIState:
        """Zero nominal controls (paper: the initial reference is zero) and the key."""
        return init_state(self.spec, self.config, key)

    # ------------------------------------------------------------- validated
    def pad_points(self, obstacle_points):
        """Validate an obstacle cloud (P, 3) and pad it to the capacity: (points, mask)."""
        cap = self.config.max_points
        if obstacle_points is None:
            pts = np.zeros((0, 3), np.float32)
        else:
            pts = np.asarray(obstacle_points, dtype=np.float32)
            if pts.size == 0:
                pts = pts.reshape(0, 3)
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise ValueError(f"obstacle_points must have shape (P, 3), got {pts.shape}")
        if not np.all(np.isfinite(pts)):
            bad = int(np.argwhere(~np.isfinite(pts))[0, 0])
            raise ValueError(f"obstacle_points contain NaN or inf (first at row {bad}: {pts[bad].tolist()})")
        if pts.shape[0] > cap:
            raise ValueError(
                f"{pts.shape[0]} obstacle points exceed the capacity max_points={cap}; "
                "raise MPPIConfig.max_points"
            )
        padded = np.zeros((cap, 3), np.float32)
        padded[: pts.shape[0]] = pts
        mask = np.zeros(cap, bool)
        mask[: pts.shape[0]] = True
        return jnp.asarray(padded), jnp.asarray(mask)

    def check_goal(self, goal):
        """Validate a goal: position (3,) or pose (4, 4), finite."""
        g = np.asarray(goal, dtype=np.float32)
        if g.shape not in ((3,), (4, 4)):
            raise ValueError(f"goal must be a position (3,) or a pose (4, 4), got shape {g.shape}")
        if not np.all(np.isfinite(g)):
            raise ValueError(f"goal contains NaN or inf: {g.tolist()}")
        return jnp.asarray(g)

    def polytopes(self, state: MPPIState, points, mask):
        """The convex model (``ncedf.convex``) of the padded cloud (points, mask): its rows
        equal to the previous step's (``state.previous``) and the others clustered apart; only
        the static rows' clusters merge by their bounding boxes (at the first step every row
        counts as moving, and distinct obstacles would chain together through the boxes of the
        clusters between them)."""
        points, mask = np.asarray(points), np.asarray(mask)
        previous, previous_mask = np.asarray(state.previous), np.asarray(state.previous_mask)
        static = static_rows(points, mask, previous, previous_mask)
        velocity = np.asarray(cloud_velocity(points, mask, previous, previous_mask, self.config.dt))
        return fit_polytopes(points[mask], self.config.convex_link, static[mask], velocity[mask], bounds=(True,))

    def follow_route(self, state: MPPIState, arc, goal, points, mask, polytopes, action):
        """The action and state after MPPI's step (module docstring, "Route"): a route's next move
        when one is being followed or a plan is due (``route_after`` + 1, 2 ``route_after`` + 1, ...
        steps without progress), else MPPI's ``action``."""
        c = self.config
        at, end = int(state.route_at), int(state.route_end)
        if at >= end - 1:  # no route, or its end reached
            stalled = int(state.stalled)
            if stalled <= c.route_after or (stalled - 1) % c.route_after or int(state.routes) >= ROUTE_TRIES:
                return action, state
            static = polytopes._replace(present=polytopes.present & ~np.any(polytopes.velocity != 0, axis=-1))
            route = plan_route(self.spec, static, np.asarray(arc), np.asarray(goal),
                               jax.random.fold_in(state.key, ROUTE_SALT), c.route)
            state = state._replace(routes=state.routes + 1)
            if route is None:  # the stall count goes on, and with it the stall escape
                return action, state
            state = state._replace(stalled=jnp.asarray(0, jnp.int32), best_goal=jnp.asarray(jnp.inf, jnp.float32))
            keep = np.unique(np.linspace(0, len(route) - 1, ROUTE_CAPACITY).round().astype(int))
            states = np.zeros((ROUTE_CAPACITY,) + route.shape[1:], np.float32)
            states[:len(keep)] = route[keep]
            state = state._replace(route=jnp.asarray(states), route_at=jnp.asarray(0, jnp.int32),
                                   route_end=jnp.asarray(len(keep), jnp.int32))
            at, end = 0, len(keep)
        route, here = np.asarray(state.route[:end]), np.asarray(arc)
        bound = c.control_bound * c.dt
        reached = at
        while reached + 1 < end and np.max(np.abs(route[reached + 1] - here)) <= bound:
            reached += 1
        u = (route[max(reached, at + 1)] - here) / c.dt
        u = u - u.mean(axis=-1, keepdims=True)  # zero-sum per link, as every state's chambers
        # One scale for every link (not project_controls' per link), so the move stays on the route's segment.
        u = u * min(1.0, c.control_bound / max(float(np.max(np.abs(u))), 1e-12))
        moves = jnp.asarray(np.stack([u, np.zeros_like(u)]), jnp.float32)  # along the route, or hold
        clear = np.asarray(_check_moves(c, self.shape, arc, moves, points, mask, polytopes=polytopes))
        needed = c.safety_margin + c.check_margin
        if clear[0] >= needed:
            if reached == end - 1:  # the route's end: MPPI again, with a fresh stall count
                state = state._replace(stalled=jnp.asarray(0, jnp.int32), best_goal=jnp.asarray(jnp.inf, jnp.float32))
            return moves[0], state._replace(route_at=jnp.asarray(reached, jnp.int32))
        return (moves[1], state) if clear[1] >= needed else (action, state)  # else MPPI's checked action

    def step(self, state: MPPIState, arc, goal, obstacle_points=None):
        """One MPPI iteration with validated inputs.

        Args:
          state: from ``init`` or the previous step.
          arc: (M, 3) current arc lengths, m (a valid state).
          goal: position (3,) or pose (4, 4) in the world frame.
          obstacle_points: (P, 3) world points, P <= max_points; None or empty
            for no obstacles.
        Returns:
          action (M, 3) m/s, the next state, and an :class:`MPPIInfo`.
        Raises:
          ValueError (InvalidStateError for the state) naming the bad value;
          FloatingPointError if the computation produced a non-finite action.
        """
        if not isinstance(state, MPPIState):
            raise ValueError(f"state must be an MPPIState from init(), got {type(state).__name__}")
        expected = (self.config.horizon, self.spec.n_links, 3)
        if tuple(np.shape(state.nominal)) != expected:
            raise ValueError(f"state.nominal must have shape {expected}, got {np.shape(state.nominal)}")
        arc = jnp.asarray(validate_state(arc, self.spec), jnp.float32)
        goal = self.check_goal(goal)
        points, mask = self.pad_points(obstacle_points)
        polytopes = self.polytopes(state, points, mask) if self.config.convex_link > 0 else None
        action, new_state, info = mppi_step(self.spec, self.config, self.shape, state, arc, goal, points, mask,
                                            polytopes)
        if self.config.route_after and goal.shape == (3,):
            action, new_state = self.follow_route(new_state, arc, goal, points, mask, polytopes, action)
        if not bool(jnp.all(jnp.isfinite(action))):
            raise FloatingPointError("MPPI produced a non-finite action; the inputs or the shape model are broken")
        return action, new_state, info

    def warm_up(self, state: MPPIState, arc, goal, obstacle_points=None) -> None:
        """Compile what :meth:`step` runs, before a closed loop's first timed step (its arguments as
        ``step``'s; results discarded): the step itself and, with ``route_after``, the route's programs,
        through a plan to where the robot's tip already is and the check of a route's moves. A route's
        first plan would otherwise compile mid-episode (23-33 s on a loaded 2-core CPU, where a warm plan
        takes 0.4-0.8 s: ``bench/route_plan.py``)."""
        jax.block_until_ready(self.step(state, arc, goal, obstacle_points))
        goal = self.check_goal(goal)
        if not (self.config.route_after and goal.shape == (3,)):
            return
        arc = jnp.asarray(validate_state(arc, self.spec), jnp.float32)  # as step's
        points, mask = self.pad_points(obstacle_points)
        polytopes = self.polytopes(state, points, mask)
        here = np.asarray(arc)
        plan_route(self.spec, polytopes, here, tips(here[None], self.spec)[0], state.key, self.config.route)
        moves = jnp.zeros((2,) + arc.shape, jnp.float32)  # as follow_route's: along the route, or hold
        jax.block_until_ready(_check_moves(self.config, self.shape, arc, moves, points, mask, polytopes=polytopes))
