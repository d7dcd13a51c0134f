"""An open cabinet: reach into it, the goal inside (a confined-space world).

A box of 0.1 m walls open towards the robot (-x): its cavity x in [3, 4.6] m, 1.8 m wide, 1.6 m
high, centred at y ~ U(-1, 1) with its floor at z ~ U(2, 3.5) (drawn from ``env_seed``). The goal is
in the cavity, 0.5 m before the back wall, halfway up. One closed mesh (five overlapping slabs,
``scenarios.solids``), observed at ``scenarios.solids.DENSITY`` points per square metre.

    python -m scenarios.cabinet --links 5 --env-seed 3
"""

from __future__ import annotations

import numpy as np

from scenarios.cli import scenario_main
from scenarios.episode import EpisodeSettings, Scene, fixed_goal_scene
from scenarios.solids import DENSITY, draw, obstacle, slab
from scenarios.world import World

CAVITY_X = (3.0, 4.6)
WIDTH, HEIGHT, WALL = 1.8, 1.6, 0.1
PLACE_RANGES = ((-1.0, 1.0), (2.0, 3.5))  # cavity centre y, floor z
TOLERANCE = 0.3
MAX_STEPS = 300


def cabinet_pieces(y: float, floor: float) -> list:
    """Floor, top, back and the two sides of a cabinet whose cavity is centred at y above ``floor``."""
    (x0, x1), w, top = CAVITY_X, WIDTH / 2, floor + HEIGHT
    outer = (y - w - WALL, y + w + WALL)
    return [slab((x0, outer[0], floor - WALL), (x1 + WALL, outer[1], floor)),
            slab((x0, outer[0], top), (x1 + WALL, outer[1], top + WALL)),
            slab((x1, outer[0], floor), (x1 + WALL, outer[1], top)),
            slab((x0, outer[0], floor), (x1, y - w, top)),
            slab((x0, y + w, floor), (x1, outer[1], top))]


def make_world(env_seed: int) -> tuple[World, np.ndarray]:
    """The world of ``env_seed`` and its goal position (3,) m."""
    y, floor = draw(env_seed, PLACE_RANGES)
    world = World(meshes=(obstacle(cabinet_pieces(y, floor), "open cabinet"),), density=DENSITY)
    return world, np.array([CAVITY_X[1] - 0.5, y, floor + HEIGHT / 2])


def build(settings: EpisodeSettings) -> Scene:
    """The scene of ``settings`` (no options)."""
    return fixed_goal_scene(settings, make_world, TOLERANCE, MAX_STEPS)


def main(argv: list[str] | None = None) -> int:
    return scenario_main("cabinet", __doc__, MAX_STEPS, argv)


if __name__ == "__main__":
    from recorder.cli import exit_with

    exit_with(main())
