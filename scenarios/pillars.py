"""A field of pillars: reach between them to the goal beyond (a confined-space world).

Nine upright cylinders of radius 0.25 m and 8 m height on a 3 x 3 grid (x in {2, 3, 4} m, y in
{-1.5, 0, 1.5}), each moved by up to 0.3 m in x and y; the goal at x = 5, y ~ U(-1, 1), z ~ U(2, 4)
(all drawn from ``env_seed``). One closed mesh (nine pillars, ``scenarios.solids``), observed at
``scenarios.solids.DENSITY`` points per square metre.

    python -m scenarios.pillars --links 5 --env-seed 3
"""

from __future__ import annotations

import numpy as np

from scenarios.cli import scenario_main
from scenarios.episode import EpisodeSettings, Scene, fixed_goal_scene
from scenarios.solids import DENSITY, draw, obstacle, pillar
from scenarios.world import World

GRID_X = (2.0, 3.0, 4.0)
GRID_Y = (-1.5, 0.0, 1.5)
JITTER = 0.3
RADIUS, HEIGHT = 0.25, 8.0
GOAL_RANGES = ((-1.0, 1.0), (2.0, 4.0))  # goal y, z
GOAL_X = 5.0
TOLERANCE = 0.3
MAX_STEPS = 300


def make_world(env_seed: int) -> tuple[World, np.ndarray]:
    """The world of ``env_seed`` and its goal position (3,) m."""
    ranges = [(-JITTER, JITTER)] * (2 * len(GRID_X) * len(GRID_Y)) + list(GOAL_RANGES)
    values = draw(env_seed, ranges)
    shifts, (y, z) = values[:-2].reshape(-1, 2), values[-2:]
    bases = [(gx + dx, gy + dy, 0.0) for (gx, gy), (dx, dy) in zip(((x, y) for x in GRID_X for y in GRID_Y), shifts)]
    world = World(meshes=(obstacle([pillar(b, RADIUS, HEIGHT) for b in bases], "pillars"),), density=DENSITY)
    return world, np.array([GOAL_X, y, z])


def build(settings: EpisodeSettings) -> Scene:
    """The scene of ``settings`` (no options)."""
    return fixed_goal_scene(settings, make_world, TOLERANCE, MAX_STEPS)


def main(argv: list[str] | None = None) -> int:
    return scenario_main("pillars", __doc__, MAX_STEPS, argv)


if __name__ == "__main__":
    from recorder.cli import exit_with

    exit_with(main())
