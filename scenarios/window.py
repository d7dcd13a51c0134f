"""A wall with a window: reach through it to the goal behind (a confined-space world).

The wall is a slab x in [3, 3.3] m, y in [-4, 4], z in [0, 14] (too tall for seven links to reach
over), with a square window of ``WINDOW`` m whose centre y ~ U(-1, 1), z ~ U(3, 4.5) is drawn from
``env_seed``; the goal is 1 m behind the wall at the window's centre. The wall is one closed mesh
(four overlapping slabs, ``scenarios.solids``), observed at ``scenarios.solids.DENSITY`` points per
square metre.

    python -m scenarios.window --links 5 --env-seed 3
"""

from __future__ import annotations

import numpy as np

from scenarios.cli import scenario_main
from scenarios.episode import EpisodeSettings, Scene, fixed_goal_scene
from scenarios.solids import DENSITY, draw, obstacle, slab
from scenarios.world import World

WALL_X = (3.0, 3.3)
WALL_Y = (-4.0, 4.0)
WALL_HEIGHT = 14.0
WINDOW = 1.2
CENTRE_RANGES = ((-1.0, 1.0), (3.0, 4.5))  # window centre y, z
BEHIND = 1.0
TOLERANCE = 0.3
MAX_STEPS = 300


def wall_pieces(y: float, z: float) -> list:
    """The wall's four slabs around a window centred at (y, z)."""
    (x0, x1), (y0, y1), h = WALL_X, WALL_Y, WINDOW / 2
    return [slab((x0, y0, 0.0), (x1, y1, z - h)), slab((x0, y0, z + h), (x1, y1, WALL_HEIGHT)),
            slab((x0, y0, z - h), (x1, y - h, z + h)), slab((x0, y + h, z - h), (x1, y1, z + h))]


def make_world(env_seed: int) -> tuple[World, np.ndarray]:
    """The world of ``env_seed`` and its goal position (3,) m."""
    y, z = draw(env_seed, CENTRE_RANGES)
    world = World(meshes=(obstacle(wall_pieces(y, z), "wall with a window"),), density=DENSITY)
    return world, np.array([WALL_X[1] + BEHIND, y, z])


def build(settings: EpisodeSettings) -> Scene:
    """The scene of ``settings`` (no options)."""
    return fixed_goal_scene(settings, make_world, TOLERANCE, MAX_STEPS)


def main(argv: list[str] | None = None) -> int:
    return scenario_main("window", __doc__, MAX_STEPS, argv)


if __name__ == "__main__":
    from recorder.cli import exit_with

    exit_with(main())
