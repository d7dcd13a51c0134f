"""An omniscient planner for worlds of moving spheres: could a controller's collision have been avoided?

The controllers observe the spheres step by step; this planner knows their
whole motion in advance (:meth:`scenarios.world.World.sphere_track`) and
searches the robot's rates for a motion that reaches the goal without touching
a sphere. A motion it finds is an exactly judged witness that the collision of
an episode was avoidable; a search that finds none is evidence (not a proof)
that no controller could have avoided it.

Motion over a horizon of T steps: rates ``u_k`` (M, 3), k = 0 .. T-1, in the
control set of the controllers' release sampling (``ncedf.mppi``): two free
rates per link ``b tanh z`` in ``(-b, b)``, the third minus their sum;
``x_{k+1} = project_state(x_k + u_k dt)`` as the episodes execute them, from
the straight robot at t = 0.

Objective, minimised by Adam from ``starts`` random sequences ``z`` in
parallel: ``|p_ee(x_T) - g| + penalty * relu(clearance - softmin_s d_s)``, with
``d_s`` the exact sphere clearances ``sdf_R(c) - rho`` (``ncedf.geometry``) at
``substeps`` instants per step (the arc lengths interpolated linearly, as the
judge does) and the soft minimum at temperature ``softness``.

Without spheres the same search gives the closest approach to a goal within a
number of steps (:func:`closest_approach`): staying still is in the control
set, so the states reachable within k steps are those reachable in exactly k,
and a motion that reaches the goal no earlier than step k + 1 collides with a
sphere that sits on the robot's base by then, whatever its rates.

A motion counts only after the episodes' exact judge
(:func:`scenarios.judge.judge_step`) has passed every step from the start to
its first state within the goal tolerance, where an episode would end.
Horizons are tried shortest first; the result is the first judged motion.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax

from ncedf.geometry import robot_signed_distance
from ncedf.mppi import MPPIConfig
from ncedf.robot import RobotSpec, forward_kinematics, project_state
from ncedf.sampling import release_controls
from scenarios.judge import judge_step
from scenarios.world import World


@dataclasses.dataclass(frozen=True)
class OracleConfig:
    """Settings of the search.

    Attributes:
      starts: random rate sequences optimised in parallel.
      iterations: Adam steps per sequence.  learning_rate: Adam's step size (on z).
      softness: temperature of the soft minimum of the clearances, m.
      clearance: clearance below which the penalty acts, m.
      penalty: weight of the clearance penalty against the goal distance (m per m).
      substeps: clearance instants per step in the objective.
      control_bound: b, m/s (the controllers' bound).
    """

    starts: int = 32
    iterations: int = 400
    learning_rate: float = 0.05
    softness: float = 0.01
    clearance: float = 0.03
    penalty: float = 20.0
    substeps: int = 4
    control_bound: float = MPPIConfig.control_bound

    def __post_init__(self):
        for name in ("starts", "iterations", "substeps"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise ValueError(f"OracleConfig.{name} must be an integer >= 1, got {value!r}")
        for name in ("learning_rate", "softness", "penalty", "control_bound"):
            if not getattr(self, name) > 0:
                raise ValueError(f"OracleConfig.{name} must be > 0, got {getattr(self, name)!r}")
        if not self.clearance >= 0:
            raise ValueError(f"OracleConfig.clearance must be >= 0, got {self.clearance!r}")


class OracleResult(NamedTuple):
    """The search's outcome.

    reach_step: the step at which the found motion first has the end effector
      within the tolerance (None: no judged motion found at any horizon).
    horizon: the horizon T of the found motion (None if none).
    arcs: (reach_step + 1, M, 3) states of the found motion up to its reach, m (None if none).
    min_distance: the judge's smallest exact distance over that motion, m (nan if none).
    """

    reach_step: int | None
    horizon: int | None
    arcs: np.ndarray | None
    min_distance: float


def rollout(z: jnp.ndarray, spec: RobotSpec, dt: float, bound: float) -> jnp.ndarray:
    """States of the rates ``b tanh z`` from the straight robot.

    Args:
      z: (T, M, 2) unconstrained free rates.  dt: step, s.  bound: b, m/s.
    Returns:
      (T + 1, M, 3) arc lengths x_0 .. x_T, m.
    """
    start = spec.straight_state().astype(z.dtype)

    def step(arc, u):
        following = project_state(arc + u * dt, spec)
        return following, following

    _, arcs = jax.lax.scan(step, start, release_controls(bound * jnp.tanh(z), bound))
    return jnp.concatenate([start[None], arcs])


def sphere_clearances(arcs: jnp.ndarray, track: jnp.ndarray, radii: jnp.ndarray, spec: RobotSpec,
                      substeps: int) -> jnp.ndarray:
    """Exact clearance to the nearest sphere at ``substeps`` instants per step.

    Args:
      arcs: (T + 1, M, 3) states, m.
      track: (T substeps + 1, S, 3) sphere centres at t = i dt / substeps, m.
      radii: (S,) m.
    Returns:
      (T substeps,) clearance at i = 1 .. T substeps, m (negative = overlap); S >= 1.
    """
    frac = jnp.arange(1, substeps + 1, dtype=arcs.dtype) / substeps
    between = arcs[:-1, None] + frac[None, :, None, None] * (arcs[1:] - arcs[:-1])[:, None]
    between = between.reshape((-1,) + arcs.shape[1:])
    distances = jax.vmap(lambda arc, centres: robot_signed_distance(centres, arc, spec))(between, track[1:])
    return jnp.min(distances - radii, axis=-1)


@functools.partial(jax.jit, static_argnums=0)
def _tips(spec: RobotSpec, arcs: jnp.ndarray) -> jnp.ndarray:
    """End-effector positions (..., 3) of states (..., M, 3), m."""
    return forward_kinematics(arcs, spec)[..., -1, :3, 3]


@functools.partial(jax.jit, static_argnums=(0, 1, 2))
def optimise(spec: RobotSpec, config: OracleConfig, dt: float, z0: jnp.ndarray, track: jnp.ndarray,
             radii: jnp.ndarray, goal: jnp.ndarray) -> jnp.ndarray:
    """Adam on the objective of the module docstring from each start.

    Args:
      z0: (B, T, M, 2) starts.  track: (T substeps + 1, S, 3) m.  radii: (S,) m.
      goal: (3,) end-effector goal, m.
    Returns:
      (B, T + 1, M, 3) optimised motions, m.
    """
    c = config

    def objective(z):
        arcs = rollout(z, spec, dt, c.control_bound)
        reach = jnp.linalg.norm(_tips(spec, arcs[-1]) - goal)
        if track.shape[1] == 0:
            return reach
        d = sphere_clearances(arcs, track, radii, spec, c.substeps)
        soft_min = -c.softness * jax.nn.logsumexp(-d / c.softness)
        return reach + c.penalty * jax.nn.relu(c.clearance - soft_min)

    adam = optax.adam(c.learning_rate)

    def descend(z):
        def iteration(carry, _):
            z, opt_state = carry
            updates, opt_state = adam.update(jax.grad(objective)(z), opt_state)
            return (optax.apply_updates(z, updates), opt_state), None

        (z, _), _ = jax.lax.scan(iteration, (z, adam.init(z)), None, c.iterations)
        return rollout(z, spec, dt, c.control_bound)

    return jax.vmap(descend)(z0)


def _position_goal(goal) -> np.ndarray:
    """``goal`` as a (3,) float64 position, m; ValueError naming its shape otherwise."""
    goal = np.asarray(goal, np.float64)
    if goal.shape != (3,):
        raise ValueError(f"the oracle takes a position goal (3,), got shape {goal.shape}")
    return goal


def closest_approach(spec: RobotSpec, goal, steps: int, dt: float, key,
                     config: OracleConfig = OracleConfig()) -> float:
    """Smallest end-effector distance to ``goal`` over the motions of ``steps`` steps (no obstacles), m.

    Every state of every optimised motion counts, so this is the closest the
    search brings the end effector within ``steps`` steps from the straight
    robot. A numerical minimum from ``config.starts`` starts (an upper bound on
    the true one; the starts agree to millimetres in the spheres' scene).

    Args:
      goal: (3,) position, m.  steps: >= 1.  dt: step, s.  key: PRNG key of the starts.
    Raises:
      ValueError naming the bad value.
    """
    goal = _position_goal(goal).astype(np.float32)
    if isinstance(steps, bool) or not isinstance(steps, int) or steps < 1:
        raise ValueError(f"steps must be an integer >= 1, got {steps!r}")
    z0 = jax.random.normal(key, (config.starts, steps, spec.n_links, 2))
    no_spheres = jnp.zeros((steps * config.substeps + 1, 0, 3), jnp.float32)
    motions = optimise(spec, config, dt, z0, no_spheres, jnp.zeros((0,), jnp.float32), jnp.asarray(goal))
    return float(np.min(np.linalg.norm(np.asarray(_tips(spec, motions)) - goal, axis=-1)))


def _judged(world: World, spec: RobotSpec, arcs: np.ndarray, dt: float) -> float | None:
    """The judge's smallest distance over the steps of ``arcs`` (None at the first collision)."""
    smallest = np.inf
    for k in range(len(arcs) - 1):
        judgement = judge_step(world, spec, arcs[k], arcs[k + 1], k * dt, dt)
        if judgement.first_collision_time is not None:
            return None
        smallest = min(smallest, judgement.min_distance)
    return float(smallest)


def plan_reach(world: World, spec: RobotSpec, goal, tolerance: float, horizons, dt: float, key,
               config: OracleConfig = OracleConfig()) -> OracleResult:
    """Search for a judged collision-free motion whose end effector comes within ``tolerance`` of ``goal``.

    Args:
      world: spheres only (static obstacles are not modelled by the search).
      goal: (3,) position, m.  tolerance: m.  horizons: horizons T to try, steps.
      dt: step, s.  key: PRNG key of the starts.
    Raises:
      ValueError naming the bad value.
    """
    if world.boxes or world.meshes or world.clouds:
        raise ValueError("the oracle models moving spheres only; this world has static obstacles")
    goal = _position_goal(goal)
    horizons = sorted({int(h) for h in horizons})
    if not horizons or horizons[0] < 1:
        raise ValueError(f"horizons must be >= 1, got {horizons}")
    radii = jnp.asarray([s.radius for s in world.spheres], jnp.float32).reshape(-1)
    for horizon in horizons:
        times = np.arange(horizon * config.substeps + 1) * dt / config.substeps
        track = jnp.asarray(world.sphere_track(times), jnp.float32)
        z0 = jax.random.normal(jax.random.fold_in(key, horizon), (config.starts, horizon, spec.n_links, 2))
        motions = optimise(spec, config, dt, z0, track, radii, jnp.asarray(goal, jnp.float32))
        tips = np.asarray(_tips(spec, motions), np.float64)  # (B, T + 1, 3)
        misses = np.linalg.norm(tips - goal, axis=-1)
        reached = misses <= tolerance
        for b in np.argsort(misses.min(axis=1)):
            if not reached[b].any():
                break
            step = int(np.argmax(reached[b]))
            arcs = np.asarray(motions[b, :step + 1], np.float64)
            smallest = _judged(world, spec, arcs, dt)
            if smallest is not None:
                return OracleResult(step, horizon, arcs, smallest)
    return OracleResult(None, None, None, float("nan"))
