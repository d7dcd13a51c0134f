"""Controller presets: factory functions that compose the core and its stages for a robot and what it observes.

* :func:`paper`: paper Sec. VI-A: 800 rollouts, horizon 20, covariance 0.05 I,
  lambda 0.02, no safety filter, the cloud alone.
* :func:`release`: the authors' public release (``docs/paper-setups.md``):
  covariance 0.1 I with the noise clipped to +-0.5, terminal weights 22 (goal)
  and 1.1 (collision), a control-perturbation cost 0.1; 800 rollouts with a
  horizon of 20 (7 above 6 links), and 1000 rollouts with a horizon of 12 where
  the obstacles are observed as balls.
* :func:`ours` (the default): the release with its two-rate sampling (the third
  rate minus the other two), a temperature for an effective sample size of 2%
  of the rollouts and the safety filter, and then by what the robot observes:

  - obstacles observed completely, as balls (centre and radius): nothing is
    hidden, so speed only shortens the time they have to reach the robot; it
    races: the unclipped plan update, the closest-approach goal cost, low-pass
    noise, a first plan updated three times before the first move (from the
    zero plan one update starts at half the rate bound), each rollout's first
    step scored over its sweep, the warm start from the executed controls,
    and a safety margin of 0.01 m beyond the balls' radius (the balls are
    observed exactly: a wider margin turns the racing robot aside near the
    goal, where a sphere closing in then meets it);
  - obstacles observed as points on surfaces whose still clusters are all
    convex: the points leave holes between them, so it closes each cluster (the
    convex model), and with the surfaces closed it races too (the unclipped
    update), is repelled less (collision weights 0.4) and escapes stalls:
    sharper weights after 30 steps without progress, and a route round the
    static polytopes;
  - surface points with a still cluster that is not convex (a wall with a
    window, a cabinet, a pipe): the convex model would close its concavity, so
    the still points are closed on a grid instead (the grid model, at the
    widest hole expected between the samples, ``Observation.gap``, less where
    that would shut the goal in; the convex parts that empty slabs cut out of
    them, a field of pillars, as polytopes); the goal cost measures the tip's distance
    along the model's free space (the guide), which leads it round walls to an
    opening; and as with the convex model it is repelled less and escapes
    stalls, its routes planned round the grid and into the opening along the
    guide's path.

  With surface points, the surface under the base (a floor, a table) is the robot's mount
  (``ncedf.mount``): the first link never reaches below its base plane, so it is not scored
  against the points there, which the obstacle model leaves out.

Nothing here depends on a scenario: a world is described by :class:`Observation`.
The evidence for each choice is in ``docs/experiments.md``.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy.spatial import cKDTree

from ncedf.controller import ControllerConfig
from ncedf.grid_model import GridModel
from ncedf.guide import Guide
from ncedf.mount import Mount, holds
from ncedf.mppi import MPPIConfig
from ncedf.obstacle_model import ConvexModel
from ncedf.recovery import RouteRecovery
from ncedf.robot import RobotSpec
from ncedf.route import RouteConfig
from ncedf.safety import SafetyFilter
from ncedf.sampling import Sampling
from ncedf.temperature import EffectiveSampleSize, StallEscape
from ncedf.validate import check_fields

#: Capacity granularity of the obstacle cloud (MPPIConfig.max_points), points: clouds of similar
#: sizes share one compiled controller.
POINT_BUCKET = 256
#: Links above which the release shortens the horizon.
RELEASE_LONG_ROBOT = 6
#: ``ours``: the effective sample size its temperature is chosen for, a share of the rollouts.
OURS_ESS = 0.02
#: ``ours`` with surface points: the convex model's single-linkage distance, m: above the longest
#: edge of a box's minimum spanning tree at 4 points per m^2 (0.88 m), below the 1.39 m between the
#: closest of the paper's boxes.
CONVEX_LINK = 1.0
#: ``ours`` with surface points: the collision weights (running and terminal) with an obstacle model.
SURFACE_W_COLL = 0.4
#: ``ours`` with surface points: steps without progress before the stall escape and the route.
STALL_STEPS = 30
#: ``ours`` with surface points: the stall escape's effective sample size, a share of the rollouts.
STALL_ESS = 0.005
#: ``ours`` with a grid model: the route's clearances (nodes, edges) against it, m (the grid's bound
#: lies below the body's true clearance by up to a cell's diagonal).
GRID_ROUTE = RouteConfig(node_clearance=0.1, edge_clearance=0.05)
#: ``ours`` with a grid model: a pose goal's corridor kept open (``GridModel``), in the robot's thickest radii.
CORRIDOR = 2.0
#: ``ours`` with surface points: the mount's reach beyond the base disk, in link lengths (there the first
#: link's bounding balls dip below the base plane; farther out its body stays well above it).
MOUNT_SPAN = 0.25
#: Neighbours whose distance estimates the samples' spacing (:func:`sampling_gap`).
GAP_NEIGHBOURS = 8
#: ``ours`` with balls: the low-pass noise's beta (a rollout keeps its direction over the horizon).
BALLS_SMOOTHING = 0.9
#: ``ours`` with balls: the updates of the first plan (``MPPIConfig.first_iterations``).
BALLS_FIRST_ITERATIONS = 3
#: ``ours`` with balls: the safety margin beyond the balls' radius, m.
BALLS_MARGIN = 0.01


@dataclasses.dataclass(frozen=True)
class Observation:
    """What the robot observes, as the presets read it.

    Attributes:
      n_points: size of the observed cloud (sets the capacity).
      ball_radius: > 0 where every point is the centre of a ball of this radius, m (the
        obstacles are observed completely); 0 where the points lie on obstacle surfaces.
      convex: every cluster of points that stays still is convex (:func:`observe` tells).
      gap: the radius of the widest hole expected between the still points, m
        (:func:`sampling_gap`; 0 without still points).
    """

    n_points: int
    ball_radius: float = 0.0
    convex: bool = True
    gap: float = 0.0

    def __post_init__(self):
        check_fields(self, counts=("n_points",), non_negative=("ball_radius", "gap"), flags=("convex",))


def observe(first, second, dt: float = MPPIConfig.dt, ball_radius: float = 0.0) -> Observation:
    """The :class:`Observation` of two successive clouds (P, 3) m, ``dt`` seconds apart, row ``i``
    the same physical point in both: whether the convex model of ``ours`` (``CONVEX_LINK``) leaves
    a still cluster out as not convex."""
    first, second = np.asarray(first, np.float32).reshape(-1, 3), np.asarray(second, np.float32).reshape(-1, 3)
    if first.shape != second.shape:
        raise ValueError(f"the two clouds must have the same rows, got {first.shape} and {second.shape}")
    mask = np.ones(len(first), bool)
    model = ConvexModel(CONVEX_LINK).fit(second, mask, first, mask, dt)
    still = second[np.all(first == second, axis=1)]
    return Observation(len(second), ball_radius=ball_radius, convex=not int(model.left_out),
                       gap=sampling_gap(still))


def sampling_gap(points: np.ndarray) -> float:
    """The radius of the widest hole expected among n points (n, 3) drawn on surfaces, m: at a
    density rho per m^2 a disc of radius r is empty with probability exp(-pi rho r^2), so the widest
    of the n points' holes has ``pi rho r^2 ~ ln n``; ``pi rho`` is estimated as k / r_k^2 from the
    median distance r_k to the k-th neighbour (k = ``GAP_NEIGHBOURS``). 0 for fewer than k + 1 points."""
    if len(points) <= GAP_NEIGHBOURS:
        return 0.0
    reach = np.median(cKDTree(points).query(points, GAP_NEIGHBOURS + 1)[0][:, -1])
    return float(reach * np.sqrt(np.log(len(points)) / GAP_NEIGHBOURS))


def point_capacity(n_points: int) -> int:
    """The smallest multiple of ``POINT_BUCKET`` that holds ``n_points`` (at least one bucket)."""
    if n_points < 0:
        raise ValueError(f"n_points must be >= 0, got {n_points}")
    return max(1, -(-n_points // POINT_BUCKET)) * POINT_BUCKET


def _margin(observation: Observation, margin: float = MPPIConfig.safety_margin) -> float:
    """The safety margin from the observed points: ``margin`` beyond the balls' radius, m."""
    return margin + observation.ball_radius


def _core(observation: Observation, samples: int, horizon: int, **fields) -> MPPIConfig:
    """The core sized to the observation: its capacity, and its margin (:func:`_margin`)."""
    return MPPIConfig(samples=samples, horizon=horizon, max_points=point_capacity(observation.n_points),
                      safety_margin=_margin(observation), **fields)


def paper(spec: RobotSpec, observation: Observation) -> ControllerConfig:
    """Paper Sec. VI-A."""
    return ControllerConfig(mppi=_core(observation, 800, 20))


def _release_sizes(spec: RobotSpec, observation: Observation) -> tuple[int, int]:
    if observation.ball_radius > 0:
        return 1000, 12
    return 800, (20 if spec.n_links <= RELEASE_LONG_ROBOT else 7)


#: The release's core fields.
RELEASE_FIELDS = {"covariance": 0.1, "w_goal_terminal": 22.0, "w_coll_terminal": 1.1, "w_perturbation": 0.1}
#: The release's clip of each noise component, m/s.
RELEASE_CLIP = 0.5


def release(spec: RobotSpec, observation: Observation) -> ControllerConfig:
    """The authors' release."""
    return ControllerConfig(mppi=_core(observation, *_release_sizes(spec, observation), **RELEASE_FIELDS),
                            sampling=Sampling(clip=RELEASE_CLIP))


def ours(spec: RobotSpec, observation: Observation) -> ControllerConfig:
    """The release with our stages, chosen by what is observed (module docstring)."""
    base = dataclasses.replace(release(spec, observation), sampling=Sampling("release", clip=RELEASE_CLIP),
                               temperature=EffectiveSampleSize(OURS_ESS), safety=SafetyFilter())
    if observation.ball_radius > 0:
        return dataclasses.replace(
            base, mppi=dataclasses.replace(base.mppi, goal_reach=True, first_iterations=BALLS_FIRST_ITERATIONS,
                                           safety_margin=_margin(observation, BALLS_MARGIN)),
            sampling=dataclasses.replace(base.sampling, smoothing=BALLS_SMOOTHING, unclipped=True),
            safety=SafetyFilter(sweep_first=True, follow_executed=True))
    if not observation.convex:
        return dataclasses.replace(
            base, mppi=dataclasses.replace(base.mppi, w_coll=SURFACE_W_COLL, w_coll_terminal=SURFACE_W_COLL),
            model=GridModel(max(observation.gap, spec.thickest), spec.thickest,
                            corridor_radius=CORRIDOR * spec.thickest, corridor_length=spec.length, link=CONVEX_LINK),
            guide=Guide(spec.thickest),
            temperature=EffectiveSampleSize(OURS_ESS, StallEscape(STALL_STEPS, STALL_ESS)),
            recovery=RouteRecovery(after=STALL_STEPS, route=GRID_ROUTE), mount=_mount(spec))
    return dataclasses.replace(
        base, mppi=dataclasses.replace(base.mppi, w_coll=SURFACE_W_COLL, w_coll_terminal=SURFACE_W_COLL),
        sampling=dataclasses.replace(base.sampling, unclipped=True),
        temperature=EffectiveSampleSize(OURS_ESS, StallEscape(STALL_STEPS, STALL_ESS)),
        model=ConvexModel(CONVEX_LINK), recovery=RouteRecovery(after=STALL_STEPS), mount=_mount(spec))


def _mount(spec: RobotSpec) -> Mount | None:
    """The base disk and ``MOUNT_SPAN`` of a link round it, where the first link keeps above its base
    plane (``ncedf.mount.holds``)."""
    return Mount(spec.radii[0] + MOUNT_SPAN * spec.length) if holds(spec) else None


#: The presets by ``--controller`` name, with one line each for ``--help``.
PRESETS = {"paper": paper, "release": release, "ours": ours}
SUMMARIES = {
    "paper": "paper Sec. VI-A: 800 rollouts, H = 20, covariance 0.05 I, lambda 0.02",
    "release": "the authors' release: covariance 0.1 I clipped to 0.5, terminal and perturbation costs",
    "ours": "release + our stages, chosen by what the robot observes (the default)",
}
DEFAULT = "ours"


def preset(name: str, spec: RobotSpec, observation: Observation, *, samples: int | None = None,
           horizon: int | None = None) -> ControllerConfig:
    """The preset ``name`` for the robot and observation, its rollouts and horizon overridden where given.

    Raises:
      ValueError naming the bad value.
    """
    if name not in PRESETS:
        raise ValueError(f"unknown controller {name!r}; choose one of {', '.join(PRESETS)}")
    config = PRESETS[name](spec, observation)
    sizes = {"samples": samples, "horizon": horizon}
    core = dataclasses.replace(config.mppi, **{k: v for k, v in sizes.items() if v is not None})
    return dataclasses.replace(config, mppi=core)
