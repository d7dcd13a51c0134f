"""A slot between two slabs: reach into it, the goal 1.5 m deep (a confined-space world).

Two horizontal slabs x in [3, 6] m, y in [-3, 3], 0.2 m thick, with a gap of ``GAP`` m between them
centred at z ~ U(2.5, 4); the goal is in the gap's middle plane 1.5 m in, at y ~ U(-1, 1) (both
drawn from ``env_seed``). One closed mesh (two slabs, ``scenarios.solids``), observed at
``scenarios.solids.DENSITY`` points per square metre.

    python -m scenarios.slot --links 5 --env-seed 3
"""

from __future__ import annotations

import numpy as np

from scenarios.cli import scenario_main
from scenarios.episode import EpisodeSettings, Scene, fixed_goal_scene
from scenarios.solids import DENSITY, draw, obstacle, slab
from scenarios.world import World

SLAB_X = (3.0, 6.0)
SLAB_Y = (-3.0, 3.0)
GAP, THICKNESS = 1.0, 0.2
PLACE_RANGES = ((2.5, 4.0), (-1.0, 1.0))  # gap centre z, goal y
DEPTH = 1.5
TOLERANCE = 0.3
MAX_STEPS = 300


def make_world(env_seed: int) -> tuple[World, np.ndarray]:
    """The world of ``env_seed`` and its goal position (3,) m."""
    z, y = draw(env_seed, PLACE_RANGES)
    (x0, x1), (y0, y1), h = SLAB_X, SLAB_Y, GAP / 2
    slabs = [slab((x0, y0, z - h - THICKNESS), (x1, y1, z - h)), slab((x0, y0, z + h), (x1, y1, z + h + THICKNESS))]
    world = World(meshes=(obstacle(slabs, "slot"),), density=DENSITY)
    return world, np.array([x0 + DEPTH, y, z])


def build(settings: EpisodeSettings) -> Scene:
    """The scene of ``settings`` (no options)."""
    return fixed_goal_scene(settings, make_world, TOLERANCE, MAX_STEPS)


def main(argv: list[str] | None = None) -> int:
    return scenario_main("slot", __doc__, MAX_STEPS, argv)


if __name__ == "__main__":
    from recorder.cli import exit_with

    exit_with(main())
