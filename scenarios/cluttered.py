"""The cluttered scene (paper Sec. VI-D, Table IV, Figs. 5-7).

Three static boxes and two spheres moving back and forth, all observed as
points on their surfaces (4 points per square metre on the box faces, 30 on
each sphere: about 500). The end effector must reach (4.8, 0, 3.6) within
0.4 m in 300 steps (15 s). The paper reports the goal reached at step 158,
82 and 43 for 4, 5 and 7 links.

    python -m scenarios.cluttered --links 7

Writes recording.rrd and recording.mcap (replay: ``rerun recording.rrd``).
"""

from __future__ import annotations

import sys

from scenarios.cli import base_settings, make_parser, run_cli
from scenarios.episode import EpisodeSettings, Scene, make_scene, require_fixed_goal, require_no_options
from scenarios.world import Box, MovingSphere, World

#: Static boxes: (centre, full edge lengths), m.
BOXES = (
    ((2.5, 0.0, 5.0), (1.0, 4.8, 3.0)),
    ((2.5, 0.0, 0.0), (1.0, 5.0, 2.0)),
    ((5.3, 0.0, 2.0), (2.0, 5.0, 1.0)),
)
#: Moving spheres: (centre at t = 0, velocity m/s); the velocity's sign flips every HALF_PERIOD.
SPHERES = (
    ((4.0, -4.5, 3.8), (0.0, 1.0, 0.0)),
    ((4.0, 0.0, 2.2), (0.0, 0.0, -0.8)),
)
SPHERE_RADIUS = 0.5
SPHERE_POINTS = 30
HALF_PERIOD = 5.0
#: Observed points per square metre of box surface.
DENSITY = 4.0
GOAL = (4.8, 0.0, 3.6)
TOLERANCE = 0.4
MAX_STEPS = 300


def make_world() -> World:
    """The paper's cluttered world (surface observation)."""
    return World(
        spheres=tuple(MovingSphere(centre, SPHERE_RADIUS, velocity, HALF_PERIOD) for centre, velocity in SPHERES),
        boxes=tuple(Box(centre, size) for centre, size in BOXES),
        density=DENSITY,
        sphere_points=SPHERE_POINTS,
        observe="surface",
    )


def build(settings: EpisodeSettings) -> Scene:
    """The cluttered scene for ``settings`` (no options; fixed goal)."""
    require_fixed_goal(settings)
    require_no_options(settings)
    return make_scene(settings, make_world(), GOAL, TOLERANCE, MAX_STEPS)


def main(argv: list[str] | None = None) -> int:
    parser = make_parser("cluttered", __doc__, max_steps=MAX_STEPS)
    return run_cli(parser, argv, lambda args: base_settings("cluttered", args))


if __name__ == "__main__":
    sys.exit(main())
