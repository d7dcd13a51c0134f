"""Dynamic spheres (paper Sec. VI-C, Table III): 8 spheres moving back and forth around the robot.

Environment ``env_seed`` (``docs/paper-setups.md``): 8 spheres of radius 0.7 m with
centres uniform in x, y in [-4, 4], z in [-1, 6], pairwise at least 1.5 m
apart; velocity components uniform in [0, 1) m/s, the sign flipping every 2 s.
The controller observes the sphere centres only (its safety margin grows by the
radius). The goal is (4, 0, 4), or with ``--goal random`` the end effector of a
random valid configuration, or with ``--goal X,Y,Z`` that position. An
environment is accepted when the goal is at least 2 m from every centre and the
straight robot at least 0.1 m from every sphere (robot-to-centre distance >
radius + 0.1); otherwise it is redrawn, deterministically: attempt ``i`` uses
``fold_in(PRNGKey(env_seed), i)``.
Success: the end effector within 0.2 m of the goal in 200 steps.

    python -m scenarios.spheres --env-seed 3 --goal random
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from ncedf.geometry import robot_signed_distance
from ncedf.robot import RobotSpec, end_effector_pose, sample_arc_lengths
from scenarios.cli import base_settings, make_parser, run_cli
from scenarios.episode import (DRAW_ATTEMPTS, EpisodeSettings, Scene, check_reach, goal_position, make_scene,
                               scenario_options, scene_robot)
from scenarios.world import MovingSphere, World

N_SPHERES = 8
RADIUS = 0.7
CENTRE_LOW = (-4.0, -4.0, -1.0)
CENTRE_HIGH = (4.0, 4.0, 6.0)
MIN_SEPARATION = 1.5
#: Velocity components are uniform in [0, SPEED), m/s.
SPEED = 1.0
HALF_PERIOD = 2.0
FIXED_GOAL = (4.0, 0.0, 4.0)
#: Smallest goal-to-centre distance, m.
GOAL_CLEARANCE = 2.0
#: Smallest distance from the straight robot to a sphere's surface, m.
START_CLEARANCE = 0.1
TOLERANCE = 0.2
MAX_STEPS = 200

_signed_distance = jax.jit(robot_signed_distance, static_argnums=2)


def accepted(centres: np.ndarray, goal: np.ndarray, spec: RobotSpec) -> bool:
    """The paper's acceptance test of an environment (see the module docstring)."""
    gaps = np.linalg.norm(centres[:, None] - centres[None], axis=-1)[np.triu_indices(len(centres), 1)]
    if np.any(gaps < MIN_SEPARATION):
        return False
    if np.any(np.linalg.norm(centres - goal, axis=-1) < GOAL_CLEARANCE):
        return False
    start = _signed_distance(jnp.asarray(centres, jnp.float32), spec.straight_state(), spec)
    return bool(np.all(np.asarray(start) > RADIUS + START_CLEARANCE))


def make_environment(env_seed: int, spec: RobotSpec, goal: str = "fixed") -> tuple[World, np.ndarray, int]:
    """The accepted environment of ``env_seed``: (world, goal position (3,), attempts used).
    ``goal``: ``fixed``, ``random`` or a position ``"X,Y,Z"`` (m; the spheres are drawn around it)."""
    position = goal_position(goal)
    if position is not None:
        check_reach(position, spec)
    low, high = np.asarray(CENTRE_LOW), np.asarray(CENTRE_HIGH)
    base = jax.random.PRNGKey(env_seed)
    for attempt in range(DRAW_ATTEMPTS):
        k_centre, k_velocity, k_goal = jax.random.split(jax.random.fold_in(base, attempt), 3)
        centres = low + (high - low) * np.asarray(jax.random.uniform(k_centre, (N_SPHERES, 3)), np.float64)
        velocities = SPEED * np.asarray(jax.random.uniform(k_velocity, (N_SPHERES, 3)), np.float64)
        if position is not None:
            target = np.asarray(position)
        elif goal == "fixed":
            target = np.asarray(FIXED_GOAL)
        else:
            arc = sample_arc_lengths(k_goal, spec, (spec.n_links,))
            target = np.asarray(end_effector_pose(arc, spec)[:3, 3], np.float64)
        if accepted(centres, target, spec):
            world = World(spheres=tuple(MovingSphere(tuple(c), RADIUS, tuple(v), HALF_PERIOD)
                                        for c, v in zip(centres.tolist(), velocities.tolist())),
                          observe="centres")
            return world, target, attempt + 1
    raise ValueError(f"no accepted environment for env_seed {env_seed} in {DRAW_ATTEMPTS} attempts")


def build(settings: EpisodeSettings) -> Scene:
    """The dynamic-spheres scene for ``settings`` (goal fixed, random or a position; no options)."""
    scenario_options(settings)
    spec = scene_robot(settings)
    world, goal, attempts = make_environment(settings.env_seed, spec, settings.goal)
    return make_scene(settings, world, goal, TOLERANCE, MAX_STEPS, environment_attempts=attempts)


def main(argv: list[str] | None = None) -> int:
    parser = make_parser("spheres", __doc__, max_steps=MAX_STEPS)
    parser.add_argument("--goal", default="fixed", metavar="GOAL",
                        help="fixed ((4, 0, 4), default), random (the tip of a random configuration) or X,Y,Z in m")
    return run_cli(parser, argv, lambda args: base_settings("spheres", args, goal=args.goal))


if __name__ == "__main__":
    from recorder.cli import exit_with

    exit_with(main())
