"""The controller: the MPPI core composed with its stages, and the validating shell around it.

A :class:`ControllerConfig` names one setting per stage, each a small frozen
dataclass of its own module:

* ``mppi``: the core (``ncedf.mppi``: sample, roll out, cost, weight, update, shift);
* ``sampling``: projected or release rates, low-pass noise, the plan's update (``ncedf.sampling``);
* ``temperature``: fixed, or chosen for an effective sample size, with a stall escape
  (``ncedf.temperature``);
* ``broad_phase``: the candidate points each rollout state is scored against, or None for
  every point (``ncedf.broad_phase``);
* ``model``: None (the observed cloud alone), the convex model of the cloud
  (``ncedf.obstacle_model``) or its grid model (``ncedf.grid_model``);
* ``guide``: None or the goal distance along the grid model's free space (``ncedf.guide``);
* ``safety``: None or the check of the executed action (``ncedf.safety``);
* ``recovery``: None or the route round the static obstacles (``ncedf.recovery``), which
  plans round the obstacle model;
* ``mount``: None or the surface under the base, which the first link cannot reach (``ncedf.mount``):
  its points count for the other links only, and the obstacle model leaves them out.

The jitted step (``ncedf.mppi.mppi_step``) runs the core with the stages that act
inside it; :class:`Controller` validates the inputs, pads the cloud to the
capacity, fits the obstacle model (numpy, outside the jitted step) and runs the
recovery around the step. The configuration's lengths and speeds are in the
reference units of ``ncedf.units``: the controller sees the robot, goal and cloud
divided by the robot's unit and returns its rates and distances in metres.
Presets that compose stages are in ``ncedf.presets``.

:func:`config_to_dict` and :func:`config_from_dict` are a recording's metadata
round trip; :func:`config_from_dict` also reads the flat settings that recordings
made before the stages hold.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ncedf.broad_phase import BroadPhase
from ncedf.grid_model import GridModel
from ncedf.guide import Guide
from ncedf.legacy import broad_phase_fields, recovery_fields
from ncedf.mount import Mount, link_mask, marked, off_mount
from ncedf.mppi import MPPIConfig, MPPIInfo, MPPIState, init_state, mppi_step
from ncedf.obstacle_model import ConvexModel
from ncedf.recovery import RouteRecovery, RouteState, no_route, plan_due, supervise
from ncedf.robot import RobotSpec, validate_state
from ncedf.route import plan_route, tips
from ncedf.safety import SafetyFilter, step_clearance
from ncedf.sampling import Sampling
from ncedf.shapes import Shape, rescaled
from ncedf.temperature import EffectiveSampleSize, Fixed, StallEscape
from ncedf.units import to_reference, unit
from ncedf.validate import unknown_fields

#: The stages' types by field (a tuple where a stage has several kinds; None allowed where listed).
STAGES = {
    "mppi": ((MPPIConfig,), False), "sampling": ((Sampling,), False),
    "temperature": ((Fixed, EffectiveSampleSize), False), "broad_phase": ((BroadPhase,), True),
    "model": ((ConvexModel, GridModel), True), "guide": ((Guide,), True), "safety": ((SafetyFilter,), True),
    "recovery": ((RouteRecovery,), True), "mount": ((Mount,), True),
}


#: The kind of a stage whose metadata names none (recordings made while it had one kind).
UNTYPED = {"model": "ConvexModel"}


@dataclasses.dataclass(frozen=True)
class ControllerConfig:
    """The core and its stages (module docstring); the defaults are the paper's controller."""

    mppi: MPPIConfig = MPPIConfig()
    sampling: Sampling = Sampling()
    temperature: Fixed | EffectiveSampleSize = Fixed()
    broad_phase: BroadPhase | None = BroadPhase()
    model: ConvexModel | GridModel | None = None
    guide: Guide | None = None
    safety: SafetyFilter | None = None
    recovery: RouteRecovery | None = None
    mount: Mount | None = None

    def __post_init__(self):
        for name, (kinds, optional) in STAGES.items():
            value = getattr(self, name)
            if not (isinstance(value, kinds) or (optional and value is None)):
                allowed = " or ".join([k.__name__ for k in kinds] + (["None"] if optional else []))
                raise ValueError(f"ControllerConfig.{name} must be {allowed}, got {value!r}")
        if self.recovery is not None and self.model is None:
            raise ValueError("ControllerConfig.recovery plans round the obstacle model: give a model too")
        if self.guide is not None and not isinstance(self.model, GridModel):
            raise ValueError("ControllerConfig.guide measures the grid model's free space: give a GridModel")


class ControllerState(NamedTuple):
    """The jitted step's :class:`ncedf.mppi.MPPIState`, the previous observation (points (P, 3),
    mask (P,); all False at first) for the obstacle model, and the route being followed."""

    mppi: MPPIState
    previous: np.ndarray
    previous_mask: np.ndarray
    route: RouteState


#: The check of a route's moves (jitted apart from the step: compiled only when a route runs).
_check_moves = jax.jit(step_clearance, static_argnums=(0, 1, 2), static_argnames="shared")


class Controller:
    """MPPI for ``spec`` with a shape representation from :func:`ncedf.shapes.make_shape`.

    ``state = controller.init(key)``, then ``action, state, info = controller.step(state, arc, goal, points)``.
    """

    def __init__(self, spec: RobotSpec, shape, config: ControllerConfig | None = None):
        if not isinstance(spec, RobotSpec):
            raise ValueError(f"spec must be a RobotSpec, got {type(spec).__name__}")
        config = ControllerConfig() if config is None else config
        if not isinstance(config, ControllerConfig):
            raise ValueError(f"config must be a ControllerConfig, got {type(config).__name__}")
        if not isinstance(shape, Shape):
            raise ValueError(f"shape must be a representation from ncedf.shapes.make_shape, got {shape!r}")
        if shape.spec.n_links != spec.n_links:
            raise ValueError(f"the shape is for {shape.spec.n_links} links, the robot has {spec.n_links}")
        self.spec, self.shape, self.config = spec, shape, config
        # The step's static settings: the model's, guide's and recovery's are host-side (fits, plans), and
        # the model's are measured from each cloud, so without them every environment shares one program.
        self.step_config = dataclasses.replace(config, model=None, guide=None, recovery=None)
        self.unit = unit(spec)
        self.core_spec, self.core_shape = to_reference(spec), rescaled(shape, to_reference(spec))
        self._guided = (None, None, None)  # the last grid, goal and guide field
        self._route_ready = False  # the route's programs compiled (prepare)

    def init(self, key) -> ControllerState:
        """Zero plan (paper: the initial reference is zero), the key, no observation yet, no route."""
        cap = self.config.mppi.max_points
        return ControllerState(init_state(self.core_spec, self.config.mppi, key), np.zeros((cap, 3), np.float32),
                               np.zeros(cap, bool), no_route(self.core_spec))

    def pad_points(self, obstacle_points):
        """Validate an obstacle cloud (P, 3) and pad it to the capacity: (points, mask)."""
        cap = self.config.mppi.max_points
        pts = np.zeros((0, 3), np.float32) if obstacle_points is None else np.asarray(obstacle_points, np.float32)
        if pts.size == 0:
            pts = pts.reshape(0, 3)
        if pts.ndim != 2 or pts.shape[1] != 3:
            raise ValueError(f"obstacle_points must have shape (P, 3), got {pts.shape}")
        if not np.all(np.isfinite(pts)):
            bad = int(np.argwhere(~np.isfinite(pts))[0, 0])
            raise ValueError(f"obstacle_points contain NaN or inf (first at row {bad}: {pts[bad].tolist()})")
        if pts.shape[0] > cap:
            raise ValueError(f"{pts.shape[0]} obstacle points exceed the capacity max_points={cap}; "
                             "raise MPPIConfig.max_points")
        padded = np.zeros((cap, 3), np.float32)
        padded[: pts.shape[0]] = pts
        mask = np.zeros(cap, bool)
        mask[: pts.shape[0]] = True
        return padded, mask

    def check_goal(self, goal):
        """Validate a goal: position (3,) or pose (4, 4), finite."""
        g = np.asarray(goal, dtype=np.float32)
        if g.shape not in ((3,), (4, 4)):
            raise ValueError(f"goal must be a position (3,) or a pose (4, 4), got shape {g.shape}")
        if not np.all(np.isfinite(g)):
            raise ValueError(f"goal contains NaN or inf: {g.tolist()}")
        return jnp.asarray(g)

    def _inputs(self, state, arc, goal, obstacle_points):
        if not isinstance(state, ControllerState):
            raise ValueError(f"state must be a ControllerState from init(), got {type(state).__name__}")
        expected = (self.config.mppi.horizon, self.spec.n_links, 3)
        if tuple(np.shape(state.mppi.nominal)) != expected:
            raise ValueError(f"the state's plan must have shape {expected}, got {np.shape(state.mppi.nominal)}")
        arc = jnp.asarray(validate_state(arc, self.spec) / self.unit, jnp.float32)
        points, mask = self.pad_points(obstacle_points)
        points, goal = points / np.float32(self.unit), to_units(self.check_goal(goal), self.unit)
        return (arc, goal, points, mask, *self.fit_model(state, points, mask, goal))

    def fit_model(self, state: ControllerState, points, mask, goal):
        """The fitted obstacle model of the padded cloud (the mount's, ``ncedf.mount``: the grid's points
        less the mount's, the polytopes under the base marked) and the guide's field (each None without
        one), in reference units."""
        model, c = self.config.model, self.config
        if model is None:
            return None, None
        if isinstance(model, ConvexModel):
            return marked(c.mount, model.fit(points, mask, state.previous, state.previous_mask, c.mppi.dt)), None
        position = np.asarray(goal)[:3, 3] if goal.shape == (4, 4) else np.asarray(goal)
        fitted = marked(c.mount, model.fit(points, off_mount(c.mount, points, mask), state.previous,
                                           state.previous_mask, c.mppi.dt, np.asarray(goal)))
        if c.guide is None:
            return fitted, None
        if self._guided[0] is not fitted.grid or self._guided[1] != position.tobytes():
            self._guided = (fitted.grid, position.tobytes(), c.guide.fit(fitted, position))
        return fitted, self._guided[2]

    def check_moves(self, arc, points, mask, model):
        """``moves (C, M, 3) -> (C,)``: the safety filter's clearance of moves from ``arc`` over a step
        (reference units)."""
        substeps = (self.config.safety or SafetyFilter()).substeps
        mask = link_mask(self.config.mount, points, mask, self.spec.n_links)
        return lambda moves: _check_moves(self.config.mppi.dt, substeps, self.config.broad_phase, self.core_shape,
                                          arc, moves, points, mask, model=model)

    def step(self, state: ControllerState, arc, goal, obstacle_points=None):
        """One control step with validated inputs.

        Args:
          state: from ``init`` or the previous step.  arc: (M, 3) current arc lengths, m (a valid state).
          goal: position (3,) or pose (4, 4) in the world frame.
          obstacle_points: (P, 3) world points, P <= max_points; None or empty for no obstacles.
        Returns:
          action (M, 3) m/s, the next :class:`ControllerState`, and an :class:`ncedf.mppi.MPPIInfo` (m).
        Raises:
          ValueError (InvalidStateError for the state) naming the bad value;
          FloatingPointError if the computation produced a non-finite action.
        """
        return self._advance(state, *self._inputs(state, arc, goal, obstacle_points))

    def _advance(self, state: ControllerState, arc, goal, points, mask, model, guide):
        """:meth:`step` on validated inputs (``_inputs``)."""
        action, mppi, info = mppi_step(self.core_spec, self.step_config, self.core_shape, state.mppi, arc, goal,
                                       points, link_mask(self.config.mount, points, mask, self.spec.n_links), model,
                                       guide)
        route, c = state.route, self.config
        if c.recovery is not None:
            action, route, mppi = supervise(c.recovery, self.core_spec, self.check_moves(arc, points, mask, model),
                                            c.mppi.safety_margin, c.mppi.control_bound, c.mppi.dt, route, mppi,
                                            arc, goal, model, action, guide)
        if not bool(jnp.all(jnp.isfinite(action))):
            raise FloatingPointError("MPPI produced a non-finite action; the inputs or the shape model are broken")
        return action * self.unit, ControllerState(mppi, points, mask, route), info_to_metres(info, self.unit)

    def warm_up(self, state: ControllerState, arc, goal, obstacle_points=None) -> None:
        """Compile the step before a closed loop's first timed step (results discarded). The
        route's programs compile where a plan first falls due (:meth:`prepare`): most episodes
        never stall, and a first run compiles them only where one does."""
        jax.block_until_ready(self._advance(state, *self._inputs(state, arc, goal, obstacle_points)))

    def may_plan(self, state: ControllerState) -> bool:
        """Whether the next :meth:`step` plans a route if it makes no progress (a plan may take
        seconds to minutes on a CPU: a loop can say so before the step)."""
        recovery = self.config.recovery
        return recovery is not None and plan_due(recovery, state.route, int(state.mppi.stalled) + 1)

    def prepare(self, state: ControllerState, arc, goal, obstacle_points=None) -> None:
        """Compile the route's programs where the next :meth:`step` may plan this controller's first
        route, so that a timed step holds the plan and not its compilation: a plan to where the
        tip already is, and the check of a route's moves (the route's second and third tries,
        ``ncedf.route.GoalLift`` and ``Bridge``, compile where an episode first needs them). Nothing otherwise;
        a loop that calls it before each timed step pays for the route only where it plans one."""
        if self._route_ready or not self.may_plan(state):
            return
        arc, goal, points, mask, model, guide = self._inputs(state, arc, goal, obstacle_points)
        here = np.asarray(arc)
        aligned = guide is not None or goal.shape == (4, 4)
        plan_route(self.core_spec, model, here, tips(here[None], self.core_spec)[0], state.mppi.key,
                   self.config.recovery.route, np.array([1.0, 0.0, 0.0]) if aligned else None)
        jax.block_until_ready(self.check_moves(arc, points, mask, model)(jnp.zeros((2,) + arc.shape, jnp.float32)))
        self._route_ready = True


def to_units(goal: jnp.ndarray, factor: float) -> jnp.ndarray:
    """A position goal (3,) or a pose goal's translation (4, 4) divided by ``factor``."""
    return goal / factor if goal.shape == (3,) else goal.at[:3, 3].divide(factor)


#: The lengths among the :class:`ncedf.mppi.MPPIInfo` fields.
INFO_LENGTHS = ("plan", "predicted_min_distance", "current_min_distance", "rollout_min_distance",
                "action_clearance")


def info_to_metres(info: MPPIInfo, factor: float) -> MPPIInfo:
    """``info`` of the controller in reference units, its lengths multiplied by ``factor`` (m per unit)."""
    return info._replace(**{name: getattr(info, name) * factor for name in INFO_LENGTHS})


def config_to_dict(config: ControllerConfig) -> dict:
    """The metadata form: the core's fields at the top level, each stage a dict (with its kind's
    ``type`` where a stage has several) or None."""
    out = dataclasses.asdict(config.mppi)
    for name, (kinds, _) in STAGES.items():
        if name == "mppi":
            continue
        stage = getattr(config, name)
        out[name] = None if stage is None else dataclasses.asdict(stage)
        if stage is not None and len(kinds) > 1:
            out[name]["type"] = type(stage).__name__
    return out


def _build(cls, fields: dict, where: str):
    """``cls(**fields)``, a ValueError naming ``where`` and the unknown fields if there are any."""
    unknown = unknown_fields(cls, fields)
    if unknown:
        raise ValueError(f"unknown {where} settings {unknown}")
    return cls(**fields)


def _stage(name: str, data):
    """The stage ``name`` from its metadata dict (None stays None)."""
    if data is None:
        return None
    kinds = {kind.__name__: kind for kind in STAGES[name][0]}
    data = dict(data)
    kind = kinds[next(iter(kinds))] if len(kinds) == 1 else kinds.get(data.pop("type", UNTYPED.get(name)))
    if kind is None:
        raise ValueError(f"unknown {name} type; the metadata must name one of {', '.join(kinds)}")
    if isinstance(data.get("escape"), dict):
        data["escape"] = _build(StallEscape, data["escape"], "escape")
    if name == "broad_phase":
        data = broad_phase_fields(data)
    if name == "recovery":
        data = recovery_fields(data)
    return _build(kind, data, name)


def config_from_dict(data: dict) -> ControllerConfig:
    """The inverse of :func:`config_to_dict` (a missing stage takes the default); the flat settings
    of older recordings are read too (``ncedf.legacy``). Raises ValueError naming a bad field."""
    if not isinstance(data.get("temperature"), dict):
        from ncedf.legacy import legacy_config

        return legacy_config(data)
    core = {name: value for name, value in data.items() if name not in STAGES}
    stages = {name: _stage(name, data[name]) for name in STAGES if name != "mppi" and name in data}
    return ControllerConfig(mppi=_build(MPPIConfig, core, "core"), **stages)

