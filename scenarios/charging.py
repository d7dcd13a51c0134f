"""Charging port (the authors' release; an SE(3) goal): reach into a port through a wall.

The wall is the box centre (5, 0, 3), size 1 x 7 x 6, with a 1 x 1 x 1 port
through it at x = 5, y ~ U(-3, 3), z ~ U(1, 5) (drawn from ``env_seed``), built
as four boxes around the hole. The goal is a full pose: the port's centre with
the end effector's approach axis (its z axis, the backbone tangent) along +x;
its rotation is Ry(90 deg), the pose of a robot bending in the xz-plane. The
controller gets the (4, 4) pose (Frobenius goal cost, paper Sec. V-B).
Success: the end effector within ``TOLERANCE`` of the port centre and its
approach axis within ``scenarios.episode.ANGLE_TOLERANCE`` (15 deg) of +x.

Eight spheres of radius 0.5 sweep in front of the wall: four at x = 3, y = -4
moving +y at 1 m/s, four at x = 2, y = 4 moving -y, at heights 3.5, 2.5, 1.5,
0.5; the sign flips every 2 s. Obstacles are observed as surface points: 5 per
square metre on the wall, 30 per sphere.

    python -m scenarios.charging --env-seed 1
"""

from __future__ import annotations

import jax
import numpy as np

from scenarios.cli import base_settings, make_parser, run_cli
from scenarios.episode import EpisodeSettings, Scene, make_scene, require_fixed_goal, scenario_options
from scenarios.world import Box, MovingSphere, World

WALL_CENTRE = (5.0, 0.0, 3.0)
WALL_SIZE = (1.0, 7.0, 6.0)
#: Edge of the cubic port, m.
PORT_SIZE = 1.0
PORT_Y = (-3.0, 3.0)
PORT_Z = (1.0, 5.0)
SPHERE_RADIUS = 0.5
SPHERE_POINTS = 30
SPHERE_HEIGHTS = (3.5, 2.5, 1.5, 0.5)
#: Two rows of spheres: (x, y at t = 0, y velocity m/s).
SPHERE_ROWS = ((3.0, -4.0, 1.0), (2.0, 4.0, -1.0))
HALF_PERIOD = 2.0
DENSITY = 5.0
TOLERANCE = 0.2
MAX_STEPS = 300
#: Goal rotation: Ry(90 deg), whose z axis (the approach direction) is +x.
APPROACH_ROTATION = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])


def port_position(env_seed: int) -> np.ndarray:
    """The port centre (5, y, z) of ``env_seed``, m."""
    u = np.asarray(jax.random.uniform(jax.random.PRNGKey(env_seed), (2,)), np.float64)
    y = PORT_Y[0] + (PORT_Y[1] - PORT_Y[0]) * u[0]
    z = PORT_Z[0] + (PORT_Z[1] - PORT_Z[0]) * u[1]
    return np.array([WALL_CENTRE[0], y, z])


def wall_boxes(port: np.ndarray) -> tuple[Box, ...]:
    """The wall as boxes around the port: below and above it (full width), left and right of it."""
    lo = np.asarray(WALL_CENTRE) - np.asarray(WALL_SIZE) / 2
    hi = np.asarray(WALL_CENTRE) + np.asarray(WALL_SIZE) / 2
    half = PORT_SIZE / 2
    y0, y1, z0, z1 = port[1] - half, port[1] + half, port[2] - half, port[2] + half
    pieces = [  # (min corner, max corner)
        ((lo[0], lo[1], lo[2]), (hi[0], hi[1], z0)),
        ((lo[0], lo[1], z1), (hi[0], hi[1], hi[2])),
        ((lo[0], lo[1], z0), (hi[0], y0, z1)),
        ((lo[0], y1, z0), (hi[0], hi[1], z1)),
    ]
    boxes = []
    for a, b in pieces:
        a, b = np.asarray(a), np.asarray(b)
        if np.all(b - a > 0):
            boxes.append(Box(tuple(((a + b) / 2).tolist()), tuple((b - a).tolist())))
    return tuple(boxes)


def make_world(env_seed: int) -> tuple[World, np.ndarray]:
    """The charging world of ``env_seed`` and its port centre (3,)."""
    port = port_position(env_seed)
    spheres = tuple(
        MovingSphere((x, y, z), SPHERE_RADIUS, (0.0, vy, 0.0), HALF_PERIOD)
        for x, y, vy in SPHERE_ROWS for z in SPHERE_HEIGHTS
    )
    world = World(spheres=spheres, boxes=wall_boxes(port), density=DENSITY, sphere_points=SPHERE_POINTS,
                  observe="surface")
    return world, port


def goal_pose(port: np.ndarray) -> np.ndarray:
    """The (4, 4) goal: at the port centre, approach axis +x."""
    pose = np.eye(4)
    pose[:3, :3] = APPROACH_ROTATION
    pose[:3, 3] = port
    return pose


def build(settings: EpisodeSettings) -> Scene:
    """The charging scene for ``settings`` (no options; the goal is the port)."""
    require_fixed_goal(settings)
    scenario_options(settings)
    world, port = make_world(settings.env_seed)
    return make_scene(settings, world, goal_pose(port), TOLERANCE, MAX_STEPS, port=port.tolist())


def main(argv: list[str] | None = None) -> int:
    parser = make_parser("charging", __doc__, max_steps=MAX_STEPS)
    return run_cli(parser, argv, lambda args: base_settings("charging", args))


if __name__ == "__main__":
    from recorder.cli import exit_with

    exit_with(main())
