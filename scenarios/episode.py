"""One closed-loop episode: observe -> plan (MPPI) -> act -> advance the world -> judge -> record.

Time is ``t_k = k dt`` (dt = the controller's step, 0.05 s). MPPI step ``k``:

1. the controller observes the obstacle cloud at ``t_k`` and plans from the
   state ``q_k`` (wall time ``solver_ms``, blocked until the result is ready;
   the step's program is compiled before the first step, and the route's before
   the step of the first plan, so no step pays for compiling);
2. the executed state ``q_{k+1} = project_state(q_k + u_k dt)`` (the
   projection repairs the float32 drift of the sum constraint);
3. the judge (``scenarios.judge.judge_step``) checks the exact robot-to-obstacle
   distance along the continuous motion ``q_k -> q_{k+1}``, obstacles moving,
   over ``[t_k, t_{k+1}]``.

Recorded rows (``step``, ``sim_time``): row ``k`` at ``t_k`` shows the state
``q_k``, the cloud the controller saw, the true obstacles at ``t_k``, the plan it
made and the metrics

  goal_distance           end-effector position to goal at ``q_k``, m;
  predicted_min_distance  the selected rollout's predicted clearance, m;
                          with spheres observed by their centres, less the
                          radius (``World.margin_extra``), so that every
                          distance is to obstacle surfaces (and the recorded
                          safety margin is the controller's less the radius);
  true_min_distance       exact clearance, min over step k's motion, m
                          (negative = penetration);
  solver_ms               wall time of the MPPI step, ms;
  current_min_distance    the representation's clearance at ``q_k``, m;
  goal_angle              (pose goals) angle between the end-effector's
                          approach axis (its z axis) and the goal's, rad.

Each row also colours the robot by link: the exact distance of every link to
the observed cloud (less ``World.margin_extra``).

Outcomes:

* ``success``: at some ``q_k`` the goal is reached (position within the
  tolerance and, for a pose goal, approach axes within ``angle_tolerance``)
  with no collision before; ``reach_step = k``. A last row ``k`` holds that
  state (no plan, solver metrics NaN, the exact distance at ``t_k``).
* ``collision``: the first checked instant with exact distance < 0, during
  step ``k`` (``first_collision_step = k``); the episode stops after row ``k``.
  An obstacle that overlaps the robot at ``t_0`` gives a collision at step 0
  before any planning (one row, ``steps = 0``).
* ``stuck``: neither after ``max_steps`` steps (last row ``max_steps``).
* ``interrupted``: SIGINT/SIGTERM while recording; the recorder finishes the
  current row, writes this outcome and closes the files.

``steps`` counts the MPPI steps executed. An episode is a pure function of its
:class:`EpisodeSettings`: the environment (obstacles, observed surface points)
comes from ``env_seed``, the controller's noise from ``seed``; the same
settings give the same metrics (except ``solver_ms``) and outcome.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import importlib
import importlib.metadata
import json
import math
import platform
import re
import signal
import sys
import time
import warnings
from typing import Any, Callable, NamedTuple

import flax.serialization
import jax
import jax.numpy as jnp
import numpy as np
from tqdm import tqdm

from ncedf.geometry import robot_link_signed_distances, robot_mesh_arrays, robot_surface_points
from ncedf.model import load_model
from ncedf.controller import Controller, ControllerConfig, config_to_dict
from ncedf.events import step_events
from ncedf.mppi import MPPIConfig
from ncedf.presets import DEFAULT, PRESETS, observe, preset
from ncedf.robot import RobotSpec, arc_lengths_to_config, forward_kinematics, project_state
from ncedf.shapes import make_shape
from ncedf.units import to_reference, unit
from recorder import Recorder, RecordingInterrupted
from recorder.recorder import FORMATS, check_writable, output_paths
from scenarios import WORLDS
from scenarios import judge as judge_mod
from scenarios.observe import make_observer

#: Runnable scenarios: the module ``scenarios.<name>`` defines ``build(settings) -> Scene``.
SCENARIOS = ("cluttered", "spheres", "custom", *WORLDS)
#: Goal kinds of the scenarios that draw goals; a goal may also be a position "X,Y,Z" (m).
GOALS = ("fixed", "random")
#: Most draws of a random environment or goal from one env_seed before a scenario gives up.
DRAW_ATTEMPTS = 10_000
#: Largest angle between the end-effector's approach axis and a pose goal's for success, rad (15 deg).
ANGLE_TOLERANCE = math.radians(15.0)
#: Points per link of the recorded backbone polylines.
BACKBONE_POINTS = 16
#: Packages whose versions go into the run metadata.
VERSIONED_PACKAGES = ("jax", "jaxlib", "numpy", "flax", "rerun-sdk", "mcap", "trimesh")
_SEED_LIMIT = 2**32


def _check_count(name: str, value, optional: bool = True) -> None:
    if value is None and optional:
        return
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise ValueError(f"{name} must be an integer >= 1, got {value!r}")


@dataclasses.dataclass(frozen=True)
class EpisodeSettings:
    """Everything that decides an episode (goes into the run metadata under ``settings``).

    Attributes:
      scenario: one of ``SCENARIOS``.
      links: robot links M.
      seed: controller noise (MPPI key).  env_seed: the environment (random
        obstacles, port position, goal, observed surface points).
      shape: robot-shape representation for the controller (``ncedf.shapes.make_shape``).
      model: N-CEDF weights (path): the robot's link geometry and, for shape ``ncedf``, its
        network; None = the shipped model.
      controller: a preset of ``ncedf.presets`` (``paper``, ``release`` or ``ours``).
      samples, horizon: override the preset's rollouts and horizon.
      max_steps: override the scenario's step budget.
      goal: ``fixed``, ``random`` or a position ``"X,Y,Z"``, m (scenarios that draw
        goals; :func:`goal_position`; kept as :func:`goal_text`).
      options: scenario-specific (name, value) text pairs, kept sorted by name; ``scale``
        (every scenario, ``SHARED_OPTIONS``) scales the scene (:func:`make_scene`).
    """

    scenario: str
    links: int
    seed: int
    env_seed: int = 0
    shape: str = "ncedf"
    model: str | None = None
    controller: str = DEFAULT
    samples: int | None = None
    horizon: int | None = None
    max_steps: int | None = None
    goal: str = "fixed"
    options: tuple[tuple[str, str], ...] = ()

    def __post_init__(self):
        if self.scenario not in SCENARIOS:
            raise ValueError(f"unknown scenario {self.scenario!r}; choose one of {', '.join(SCENARIOS)}")
        _check_count("links", self.links, optional=False)
        for name in ("seed", "env_seed"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not 0 <= value < _SEED_LIMIT:
                raise ValueError(f"{name} must be an integer in [0, 2^32), got {value!r}")
        if not isinstance(self.shape, str) or not self.shape:
            raise ValueError(f"shape must be a representation name, got {self.shape!r}")
        if self.model is not None and (not isinstance(self.model, str) or not self.model):
            raise ValueError(f"model must be a path or None, got {self.model!r}")
        if self.controller not in PRESETS:
            raise ValueError(f"unknown controller {self.controller!r}; choose one of {', '.join(PRESETS)}")
        for name in ("samples", "horizon", "max_steps"):
            _check_count(name, getattr(self, name))
        object.__setattr__(self, "goal", goal_text(self.goal))
        try:
            pairs = tuple((str(k), str(v)) for k, v in self.options)
        except (TypeError, ValueError):
            raise ValueError(f"options must be (name, value) pairs, got {self.options!r}") from None
        names = [k for k, _ in pairs]
        if len(set(names)) != len(names):
            raise ValueError(f"options name a setting twice: {names}")
        object.__setattr__(self, "options", tuple(sorted(pairs)))

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict (options as [name, value] lists); ``from_dict`` inverts it."""
        d = dataclasses.asdict(self)
        d["options"] = [list(pair) for pair in self.options]
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "EpisodeSettings":
        """Rebuild settings from ``to_dict`` output (e.g. a recording's ``settings`` metadata)."""
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = set(d) - names
        if unknown:
            raise ValueError(f"unknown episode settings {sorted(unknown)}")
        d = dict(d)
        d["options"] = tuple(tuple(pair) for pair in d.get("options", ()))
        return cls(**d)


def goal_position(goal: str) -> tuple[float, float, float] | None:
    """A goal given as a position ``"X,Y,Z"``: its three floats, m; None for a kind in ``GOALS``;
    ValueError naming anything else."""
    if goal in GOALS:
        return None
    try:
        return option_vector("goal", goal)
    except (ValueError, AttributeError):
        raise ValueError(f"goal must be {', '.join(GOALS)} or a position X,Y,Z in m, got {goal!r}") from None


def goal_text(goal: str) -> str:
    """A goal's canonical text: a kind in ``GOALS`` as it is, a position as its floats' repr
    ``"X,Y,Z"``; ValueError naming anything else."""
    position = goal_position(goal)
    return goal if position is None else ",".join(map(repr, position))


class GoalWarning(UserWarning):
    """A goal that no motion reaches: the episode runs on (and ends stuck)."""


def beyond_reach(position, spec: RobotSpec, tolerance: float = 0.0) -> str | None:
    """Why a goal position (3,) m cannot be reached: it lies farther than the robot's length plus
    ``tolerance`` m from its base (the origin); None where it does not."""
    distance = float(np.linalg.norm(position))
    reach = spec.n_links * spec.length
    if distance <= reach + tolerance:
        return None
    return (f"goal {tuple(float(v) for v in position)} is {distance:.2f} m from the base, beyond the reach of the "
            f"{spec.n_links}-link robot ({reach:g} m)")


def check_reach(position, spec: RobotSpec) -> None:
    """ValueError when a goal position (3,) m lies beyond the robot's length from its base (the origin)."""
    reason = beyond_reach(position, spec)
    if reason is not None:
        raise ValueError(reason)


def episode_name(settings: EpisodeSettings) -> str:
    """A file-name-safe name, unique per settings: readable fields + a hash of all of them."""
    digest = hashlib.sha256(json.dumps(settings.to_dict(), sort_keys=True).encode()).hexdigest()[:10]
    shape = re.sub(r"[^A-Za-z0-9]+", "-", settings.shape)
    return (f"{settings.scenario}_L{settings.links}_{shape}_{settings.controller}"
            f"_env{settings.env_seed}_s{settings.seed}_{digest}")


@dataclasses.dataclass(frozen=True)
class Scene:
    """What a scenario builds for an episode.

    Attributes:
      world: obstacles (``scenarios.world.World``).  observer: its observation, drawn from env_seed.
      goal: position (3,) or pose (4, 4), world frame, m.
      tolerance: goal position tolerance, m.  angle_tolerance: pose goals, rad.
      max_steps: step budget.  spec: the robot.  config: the controller's settings.
      info: scenario-specific facts for the run metadata (JSON-ready).
    """

    world: Any
    observer: Any
    goal: np.ndarray
    tolerance: float
    max_steps: int
    spec: RobotSpec
    config: ControllerConfig
    angle_tolerance: float | None = None
    info: dict = dataclasses.field(default_factory=dict)


def robot_spec(settings: EpisodeSettings) -> RobotSpec:
    """The robot: ``settings.links`` links of the geometry the model (``settings.model``, else the
    shipped one) was trained for; ValueError if the model is a tapered robot's of other links."""
    model = load_model(settings.model).spec
    if model.tapered and model.n_links != settings.links:
        raise ValueError(f"the model {settings.model} is for a tapered robot of {model.n_links} links, "
                         f"not {settings.links}: run it with --links {model.n_links}")
    return RobotSpec(settings.links, **model.link_geometry())


def scene_scale(settings: EpisodeSettings) -> float:
    """The shared option ``scale`` (default 1); ValueError naming a bad one."""
    return option_positive("scale", dict(settings.options).get("scale", "1"))


def scene_robot(settings: EpisodeSettings) -> RobotSpec:
    """The robot in the scene as a scenario builds it, before :func:`make_scene` scales it by ``scale``."""
    return robot_spec(settings).scaled(1.0 / scene_scale(settings))


def make_scene(settings: EpisodeSettings, world, goal, tolerance: float, max_steps: int, **info) -> Scene:
    """Assemble a Scene: the world, goal and tolerance as built scaled by the option ``scale`` about
    the base, the observer from ``env_seed``, the robot, and the controller preset for the robot and
    what it observes (``ncedf.presets.Observation``, both in the robot's units, ``ncedf.units``).

    ``settings.max_steps`` overrides ``max_steps``; a (4, 4) goal is a pose goal
    (judged with ``ANGLE_TOLERANCE``). A goal beyond the robot's reach is warned of.
    """
    goal = np.asarray(goal, dtype=np.float64)
    if goal.shape not in ((3,), (4, 4)) or not np.all(np.isfinite(goal)):
        raise ValueError(f"goal must be a finite position (3,) or pose (4, 4), got {goal.tolist()}")
    if not tolerance > 0:
        raise ValueError(f"goal tolerance must be > 0, got {tolerance}")
    factor = scene_scale(settings)
    world, tolerance = world.scaled(factor), tolerance * factor
    if goal.shape == (4, 4):
        goal[:3, 3] *= factor
    else:
        goal = goal * factor
    observer = make_observer(world, settings.env_seed)
    spec = robot_spec(settings)
    reason = beyond_reach(goal[:3, 3] if goal.shape == (4, 4) else goal, spec, tolerance)
    if reason is not None:  # the episode runs on (it ends stuck): a scenario's own goal with a short robot
        warnings.warn(GoalWarning(f"{reason}: it cannot be reached"), stacklevel=2)
    dt, u = MPPIConfig.dt, unit(spec)
    observation = observe(observer.observe(0.0) / u, observer.observe(dt) / u, dt, ball_radius=world.margin_extra / u)
    config = preset(settings.controller, to_reference(spec), observation, samples=settings.samples,
                    horizon=settings.horizon)
    return Scene(world=world, observer=observer, goal=goal, tolerance=float(tolerance),
                 max_steps=settings.max_steps or max_steps, spec=spec, config=config,
                 angle_tolerance=ANGLE_TOLERANCE if goal.shape == (4, 4) else None, info=info)


def build_scene(settings: EpisodeSettings) -> Scene:
    """The scene of ``settings.scenario`` (``scenarios.<scenario>.build``)."""
    return importlib.import_module(f"scenarios.{settings.scenario}").build(settings)


def fixed_goal_scene(settings: EpisodeSettings, make_world: Callable, tolerance: float, max_steps: int) -> Scene:
    """The scene of a runner without options whose ``make_world(env_seed)`` gives (world, goal position)."""
    require_fixed_goal(settings)
    scenario_options(settings)
    world, goal = make_world(settings.env_seed)
    return make_scene(settings, world, goal, tolerance, max_steps, goal_position=np.asarray(goal).tolist())


def require_fixed_goal(settings: EpisodeSettings) -> None:
    """For scenarios with one goal: refuse ``goal='random'``."""
    if settings.goal != "fixed":
        raise ValueError(f"scenario {settings.scenario} has a fixed goal; goal {settings.goal!r} is for spheres "
                         "and cluttered")


#: Options every scenario takes (read by :func:`make_scene`, not by the scenario).
SHARED_OPTIONS = ("scale",)


def scenario_options(settings: EpisodeSettings, known: tuple[str, ...] = ()) -> dict[str, str]:
    """The scenario's own options of ``settings`` by name (``SHARED_OPTIONS`` left out); ValueError
    naming any not in ``known``."""
    options = {k: v for k, v in settings.options if k not in SHARED_OPTIONS}
    unknown = sorted(set(options) - set(known))
    if unknown and not known:
        raise ValueError(f"scenario {settings.scenario} takes no options, got {options}")
    if unknown:
        raise ValueError(f"unknown {settings.scenario}-scenario options {unknown}; known: {', '.join(known)}")
    return options


def option_vector(name: str, text: str) -> tuple[float, float, float]:
    """``"X,Y,Z"`` -> three finite floats; ValueError naming the option and text."""
    try:
        values = tuple(float(v) for v in text.split(","))
    except ValueError:
        values = ()
    if len(values) != 3 or not all(math.isfinite(v) for v in values):
        raise ValueError(f"{name} {text!r} is not three numbers X,Y,Z")
    return values


def option_positive(name: str, text: str) -> float:
    """A finite number > 0; ValueError naming the option and text."""
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not math.isfinite(value) or value <= 0:
        raise ValueError(f"{name} {text!r} is not a number > 0")
    return value


# ------------------------------------------------------------------ geometry per step
@functools.partial(jax.jit, static_argnums=0)
def _robot_view(spec: RobotSpec, arc, points, mask, margin_extra):
    """Frames (M+1, 4, 4), theta and phi (M,), backbone polylines (M, K, 3) and the
    per-link clearance to the observed cloud (M,) (exact geometry, minus ``margin_extra``)."""
    frames = forward_kinematics(arc, spec)
    theta, phi = arc_lengths_to_config(arc, spec)
    u = jnp.linspace(0.0, 1.0, BACKBONE_POINTS)
    axis = jnp.stack([u, jnp.zeros_like(u), jnp.zeros_like(u)], axis=-1)  # w = 0: the backbone
    backbone = robot_surface_points(jnp.broadcast_to(axis, (spec.n_links, BACKBONE_POINTS, 3)), arc, spec)
    d = robot_link_signed_distances(points, arc, spec)
    clearance = jnp.min(jnp.where(mask[None], d, jnp.inf), axis=1) - margin_extra
    return frames, theta, phi, backbone, clearance


def goal_errors(ee_pose: np.ndarray, goal: np.ndarray) -> tuple[float, float | None]:
    """(position distance m, approach-axis angle rad or None) from the end-effector pose (4, 4) to a goal."""
    if goal.shape == (4, 4):
        cos = float(np.clip(np.dot(ee_pose[:3, 2], goal[:3, 2]), -1.0, 1.0))
        return float(np.linalg.norm(ee_pose[:3, 3] - goal[:3, 3])), math.acos(cos)
    return float(np.linalg.norm(ee_pose[:3, 3] - goal)), None


def goal_reached(scene: Scene, distance: float, angle: float | None) -> bool:
    """Position within the tolerance and, for a pose goal, the approach axes within the angle tolerance."""
    if distance > scene.tolerance:
        return False
    return angle is None or angle <= scene.angle_tolerance


def obstacle_shapes(world, t: float) -> dict:
    """True sphere and box geometry at time t in the recorder's form."""
    shapes = {}
    if world.spheres:
        shapes["spheres"] = {"centers": world.sphere_centres(t),
                             "radii": np.array([s.radius for s in world.spheres])}
    if world.boxes:
        shapes["boxes"] = {"centers": np.array([b.centre for b in world.boxes]),
                           "sizes": np.array([b.size for b in world.boxes])}
    return shapes


def describe_world(world) -> dict:
    """JSON-ready description of a world (meshes and clouds summarised by counts and bounds)."""

    def bounds(points):
        points = np.asarray(points, dtype=np.float64)
        return [points.min(axis=0).tolist(), points.max(axis=0).tolist()] if len(points) else None

    return {
        "observe": world.observe,
        "density": world.density,
        "sphere_points": world.sphere_points,
        "cloud_voxel": world.cloud_voxel,
        "margin_extra": world.margin_extra,
        "spheres": [dataclasses.asdict(s) for s in world.spheres],
        "boxes": [dataclasses.asdict(b) for b in world.boxes],
        "meshes": [{"vertices": len(m.vertices), "faces": len(m.faces), "bounds": bounds(m.vertices)}
                   for m in world.meshes],
        "clouds": [{"points": len(c.points), "bounds": bounds(c.points)} for c in world.clouds],
    }


def package_versions() -> dict[str, str | None]:
    """Versions of Python and the packages an episode depends on."""
    versions = {"python": platform.python_version()}
    for name in VERSIONED_PACKAGES:
        try:
            versions[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            versions[name] = None
    return versions


def model_description(model, path: str | None) -> dict:
    """Model id (hash of its weights), file, architecture and metrics from its metadata."""
    digest = hashlib.sha256(flax.serialization.to_bytes(model.params)).hexdigest()
    meta = model.metadata  # nested dicts arrive frozen as tuples of (key, value) pairs
    architecture, metrics, dataset = (dict(meta.get(k) or ()) for k in ("architecture", "metrics", "dataset"))
    return {
        "id": digest[:16],
        "path": path or "shipped default",
        "architecture": architecture,
        "metrics": metrics,
        "dataset_hash": dataset.get("hash"),
        "command": meta.get("command"),
    }


# ------------------------------------------------------------------ results
@dataclasses.dataclass(frozen=True)
class EpisodeResult:
    """How an episode ended (see the module docstring for the fields' meaning).

    solver_ms_mean / solver_ms_std: over the MPPI steps (NaN if none).
    final_goal_distance: at the last recorded state, m.
    signal: the signal name when interrupted.  paths: the recordings written.
    """

    outcome: str
    steps: int
    reach_step: int | None
    min_true_distance: float
    first_collision_step: int | None
    solver_ms_mean: float
    solver_ms_std: float
    final_goal_distance: float
    signal: str | None = None
    paths: tuple[str, ...] = ()

    def outcome_record(self) -> dict[str, Any]:
        """The ``/outcome`` event."""
        return {"outcome": self.outcome, "steps": self.steps, "reach_step": self.reach_step,
                "min_true_distance": self.min_true_distance if math.isfinite(self.min_true_distance) else None,
                "first_collision_step": self.first_collision_step}


# ------------------------------------------------------------------ the episode
class Episode:
    """A prepared episode: scene, controller and observation built and validated, nothing written.

    ``Episode(settings)`` raises ValueError (``ncedf.model.ModelError``,
    ``scenarios.world.WorldError`` included) naming a bad setting; ``run`` then
    runs it once.
    """

    def __init__(self, settings: EpisodeSettings):
        if not isinstance(settings, EpisodeSettings):
            raise ValueError(f"settings must be EpisodeSettings, got {type(settings).__name__}")
        self.settings = settings
        self.scene = scene = build_scene(settings)
        model = load_model(settings.model) if settings.shape == "ncedf" else None
        self.shape = make_shape(settings.shape, scene.spec, model=model)
        self.model = None if model is None else model_description(model, settings.model)
        self.mppi = Controller(scene.spec, self.shape, scene.config)

    def run_meta(self, mesh_every: int) -> dict[str, Any]:
        """The ``/run`` metadata: everything needed to rerun the episode. ``mppi`` is the controller's
        configuration in reference units (``ncedf.units``), ``mppi_unit`` the metres per unit."""
        s, scene = self.settings, self.scene
        return {
            "scenario": s.scenario,
            "links": s.links,
            "shape": s.shape,
            "seed": s.seed,
            "env_seed": s.env_seed,
            "controller": s.controller,
            "settings": s.to_dict(),
            "mppi": config_to_dict(scene.config),
            "mppi_unit": self.mppi.unit,
            "robot": dataclasses.asdict(scene.spec),
            "model": self.model,
            "world": describe_world(scene.world),
            "observed_points": scene.observer.n_points,
            "goal": scene.goal.tolist(),
            "goal_tolerance": scene.tolerance,
            "angle_tolerance": scene.angle_tolerance,
            "max_steps": scene.max_steps,
            "scene": scene.info,
            "recording": {"mesh_every": mesh_every},
            "versions": package_versions(),
        }

    def run(self, out=None, formats=FORMATS, overwrite: bool = False, mesh_every: int = 1,
            viewer: bool = False, progress: bool = False) -> EpisodeResult:
        """Run the episode; record it to ``out`` (.rrd/.mcap per ``formats``) unless ``out`` is None.

        Args:
          out: recording path without suffix, or None for no recording.
          mesh_every: log the robot mesh every this many steps (and on the last row).
          viewer: also stream to a live Rerun viewer.  progress: a tqdm bar on stderr.
        Raises:
          recorder.RecorderError: an existing output (without ``overwrite``) or
            an unwritable folder, before anything is opened.
        """
        _check_count("mesh_every", mesh_every, optional=False)
        if out is not None:  # before compiling; the Recorder checks again
            check_writable(output_paths(out, formats), overwrite)
        scene, mppi, spec = self.scene, self.mppi, self.scene.spec
        goal_jnp = mppi.check_goal(scene.goal)
        arc = np.asarray(spec.straight_state(), dtype=np.float32)
        # The start is judged like a step, as the motion of length zero at t_0 (this also
        # compiles the judge before the progress bar starts).
        start_distance = judge_mod.judge_step(scene.world, spec, arc, arc, 0.0, 0.0).min_distance
        # Compile the controller's step before the first timed step.
        mppi.warm_up(mppi.init(jax.random.PRNGKey(self.settings.seed)), arc, goal_jnp, scene.observer.observe(0.0))

        recorder = None
        if out is not None:
            recorder = Recorder(out, self.run_meta(mesh_every), formats, overwrite=overwrite,
                                safety_margin=scene.config.mppi.safety_margin * mppi.unit - scene.world.margin_extra,
                                goal_tolerance=scene.tolerance, viewer=viewer)
        loop = _Loop(self, recorder, mesh_every, progress)
        try:
            if recorder is not None:  # inside: a failure here still closes the files
                recorder.log_meshes([(mesh.vertices, mesh.faces) for mesh in scene.world.meshes])
            result = loop.run(arc, goal_jnp, start_distance)
        except RecordingInterrupted as exc:
            result = loop.result("interrupted", signal_name=signal.Signals(exc.signum).name)
        except BaseException:
            if recorder is not None and not recorder.closed:
                recorder.finish(loop.result("interrupted").outcome_record())
            raise
        finally:
            loop.close()
        if recorder is not None:
            recorder.finish(result.outcome_record())
            result = dataclasses.replace(result, paths=tuple(str(p) for p in recorder.paths.values()))
        return result


class _View(NamedTuple):
    """The robot at one row: frames (M+1, 4, 4), theta, phi (M,), backbone (M, K, 3), per-link
    clearance to the observed cloud (M,), goal position error (m) and approach angle (rad or None)."""

    frames: np.ndarray
    theta: np.ndarray
    phi: np.ndarray
    backbone: np.ndarray
    clearance: np.ndarray
    goal_distance: float
    goal_angle: float | None


class _Loop:
    """The mutable bookkeeping of one run of an :class:`Episode`."""

    def __init__(self, episode: Episode, recorder, mesh_every: int, progress: bool):
        self.episode = episode
        self.scene = episode.scene
        self.recorder = recorder
        self.mesh_every = mesh_every
        self.faces = None
        self.solver_ms: list[float] = []
        self.steps = 0
        self.min_true = math.inf
        self.goal_distance = math.nan
        self.reach_step = None
        self.first_collision_step = None
        self.bar = tqdm(total=self.scene.max_steps, desc=episode.settings.scenario, unit="step",
                        disable=not progress, file=sys.stderr, dynamic_ncols=True)

    def close(self) -> None:
        self.bar.close()

    def log(self, level: str, text: str) -> None:
        """A line in the recording's log, at the last recorded step."""
        if self.recorder is not None and not self.recorder.closed:
            self.recorder.log_text(text, level)

    def outcome_line(self, outcome: str, signal_name: str | None) -> tuple[str, str]:
        """The log line of the episode's end."""
        if outcome == "success":
            return "info", f"goal reached at step {self.reach_step}, {self.goal_distance:.3f} m from it"
        if outcome == "collision":
            return "error", f"collision during step {self.first_collision_step}: exact distance {self.min_true:.3f} m"
        if outcome == "stuck":
            return "warning", f"goal not reached in {self.steps} steps: {self.goal_distance:.3f} m from it"
        return "warning", f"interrupted ({signal_name or 'an error'}) after {self.steps} steps"

    def result(self, outcome: str, signal_name: str | None = None) -> EpisodeResult:
        self.log(*self.outcome_line(outcome, signal_name))
        ms = np.asarray(self.solver_ms)
        return EpisodeResult(
            outcome=outcome, steps=self.steps, reach_step=self.reach_step, min_true_distance=self.min_true,
            first_collision_step=self.first_collision_step,
            solver_ms_mean=float(ms.mean()) if ms.size else math.nan,
            solver_ms_std=float(ms.std()) if ms.size else math.nan,
            final_goal_distance=self.goal_distance, signal=signal_name)

    def run(self, arc: np.ndarray, goal_jnp, distance: float) -> EpisodeResult:
        """From the straight state ``arc`` at exact distance ``distance``; the result."""
        scene, mppi, spec = self.scene, self.episode.mppi, self.scene.spec
        world, dt = scene.world, scene.config.mppi.dt
        state = mppi.init(jax.random.PRNGKey(self.episode.settings.seed))
        for k in range(scene.max_steps + 1):
            t = k * dt
            points = scene.observer.observe(t)
            view = self.view(arc, points)
            if k == 0 and distance < 0:
                self.first_collision_step = 0
                self.min_true = distance
                self.record(k, t, arc, points, view, None, {"true_min_distance": distance}, last=True)
                return self.result("collision")
            reached = goal_reached(scene, view.goal_distance, view.goal_angle)
            if reached or k == scene.max_steps:
                self.min_true = min(self.min_true, distance)
                self.record(k, t, arc, points, view, None, {"true_min_distance": distance}, last=True)
                if reached:
                    self.reach_step = k
                    return self.result("success")
                return self.result("stuck")

            mppi.prepare(state, arc, goal_jnp, points)  # a route's first plan: compiled outside the timing
            planning = mppi.may_plan(state)
            if planning:  # the bar stands still meanwhile
                self.bar.set_description(f"{self.episode.settings.scenario}: planning a route", refresh=True)
            start, before = time.perf_counter(), state
            action, state, info = jax.block_until_ready(mppi.step(state, arc, goal_jnp, points))
            self.solver_ms.append((time.perf_counter() - start) * 1e3)
            if planning:
                self.bar.set_description(self.episode.settings.scenario, refresh=False)
            arc_next = np.asarray(project_state(arc + np.asarray(action) * dt, spec), dtype=np.float32)
            judgement = judge_mod.judge_step(world, spec, arc, arc_next, t, dt)
            self.min_true = min(self.min_true, judgement.min_distance)
            self.steps = k + 1
            collided = judgement.first_collision_time is not None
            if collided:
                self.first_collision_step = k
            self.record(k, t, arc, points, view, np.asarray(info.plan), {
                "true_min_distance": judgement.min_distance,
                "predicted_min_distance": float(info.predicted_min_distance) - world.margin_extra,
                "solver_ms": self.solver_ms[-1],
                "current_min_distance": float(info.current_min_distance) - world.margin_extra,
            }, last=collided)
            for level, text in step_events(mppi.config, before, state, info):
                self.log(level, f"step {k}: {text}")
            self.bar.update(1)
            if collided:
                return self.result("collision")
            arc, distance = arc_next, judgement.end_distance  # the exact distance at t_{k+1}
        raise AssertionError("unreachable: the loop returns at max_steps")

    def view(self, arc: np.ndarray, points: np.ndarray) -> _View:
        padded, mask = self.episode.mppi.pad_points(points)
        out = _robot_view(self.scene.spec, jnp.asarray(arc), padded, mask, self.scene.world.margin_extra)
        frames, theta, phi, backbone, clearance = (np.asarray(x) for x in out)
        distance, angle = goal_errors(frames[-1].astype(np.float64), self.scene.goal)
        return _View(frames, theta, phi, backbone, clearance, distance, angle)

    def record(self, k: int, t: float, arc, points, view: _View, plan, metrics: dict, last: bool) -> None:
        """Log row k (state q_k at t_k) and show it on the progress bar."""
        self.goal_distance = view.goal_distance
        row = {"goal_distance": view.goal_distance, "predicted_min_distance": math.nan, "solver_ms": math.nan,
               **metrics}
        if view.goal_angle is not None:
            row["goal_angle"] = view.goal_angle
        self.bar.set_postfix(goal=f"{view.goal_distance:.2f} m", clearance=f"{row['true_min_distance']:.3f} m",
                             refresh=False)
        if self.recorder is None:
            return
        mesh = {}
        if last or k % self.mesh_every == 0:
            vertices, faces = robot_mesh_arrays(arc, self.scene.spec)
            if self.faces is None:
                self.faces = faces
            mesh = {"mesh_vertices": vertices, "mesh_triangles": self.faces}
        state = {"arc_lengths": arc, "theta": view.theta, "phi": view.phi, "ee_position": view.frames[-1, :3, 3]}
        self.recorder.log_step(k, t, metrics=row, backbone=view.backbone, obstacle_points=points,
                               obstacle_shapes=obstacle_shapes(self.scene.world, t), goal=self.scene.goal,
                               plan=plan, state=state, link_clearance=view.clearance, **mesh)


def run_episode(settings: EpisodeSettings, out=None, formats=FORMATS, overwrite: bool = False,
                mesh_every: int = 1, viewer: bool = False, progress: bool = False) -> EpisodeResult:
    """Build and run one episode (see :meth:`Episode.run`); a pure function of ``settings``."""
    return Episode(settings).run(out, formats=formats, overwrite=overwrite, mesh_every=mesh_every,
                                 viewer=viewer, progress=progress)
