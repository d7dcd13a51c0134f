"""A pipe to reach into: the goal 1 m inside it (a confined-space world).

A straight pipe along +x from x = 3 to 6 m, inner radius ``INNER`` (room for the robot's 0.4 m
diameter and a margin), 0.1 m wall, its axis at y ~ U(-1, 1), z ~ U(2.5, 4) (drawn from
``env_seed``). The goal is on the axis 1 m inside. One closed mesh (an annular solid,
``scenarios.solids``), observed at ``scenarios.solids.DENSITY`` points per square metre.

    python -m scenarios.pipe --links 5 --env-seed 3
"""

from __future__ import annotations

import numpy as np

from scenarios.cli import scenario_main
from scenarios.episode import EpisodeSettings, Scene, fixed_goal_scene
from scenarios.solids import DENSITY, draw, obstacle, tube
from scenarios.world import World

PIPE_X = (3.0, 6.0)
INNER, OUTER = 0.7, 0.8
AXIS_RANGES = ((-1.0, 1.0), (2.5, 4.0))  # axis y, z
DEPTH = 1.0
TOLERANCE = 0.3
MAX_STEPS = 300


def make_world(env_seed: int) -> tuple[World, np.ndarray]:
    """The world of ``env_seed`` and its goal position (3,) m."""
    y, z = draw(env_seed, AXIS_RANGES)
    pipe = tube((PIPE_X[0], y, z), (PIPE_X[1], y, z), INNER, OUTER)
    world = World(meshes=(obstacle([pipe], "pipe"),), density=DENSITY)
    return world, np.array([PIPE_X[0] + DEPTH, y, z])


def build(settings: EpisodeSettings) -> Scene:
    """The scene of ``settings`` (no options)."""
    return fixed_goal_scene(settings, make_world, TOLERANCE, MAX_STEPS)


def main(argv: list[str] | None = None) -> int:
    return scenario_main("pipe", __doc__, MAX_STEPS, argv)


if __name__ == "__main__":
    from recorder.cli import exit_with

    exit_with(main())
