"""The cluttered scene (paper Sec. VI-D, Table IV, Figs. 5-7).

Three static boxes and two spheres moving back and forth, all observed as
points on their surfaces (4 points per square metre on the box faces, 30 on
each sphere: about 500). The end effector must reach (4.8, 0, 3.6) within
0.4 m in 300 steps (15 s). The paper reports the goal reached at step 158,
82 and 43 for 4, 5 and 7 links.

    python -m scenarios.cluttered --links 7

Writes recording.rrd and recording.mcap (replay: ``rerun recording.rrd``).

Scenario option (kept in the run's settings when given): density, the observed
points per square metre of box face (``--density 16``; sweeps: ``--option
density=16``). The paper's 4 leaves holes up to 0.8 m across in the cloud.
"""

from __future__ import annotations

from scenarios.cli import base_settings, make_parser, run_cli
from scenarios.episode import EpisodeSettings, Scene, make_scene, option_positive, require_fixed_goal, scenario_options
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
OPTIONS = ("density",)


def make_world(density: float = DENSITY) -> World:
    """The paper's cluttered world, its box faces observed at ``density`` points per m^2."""
    return World(
        spheres=tuple(MovingSphere(centre, SPHERE_RADIUS, velocity, HALF_PERIOD) for centre, velocity in SPHERES),
        boxes=tuple(Box(centre, size) for centre, size in BOXES),
        density=density,
        sphere_points=SPHERE_POINTS,
        observe="surface",
    )


def build(settings: EpisodeSettings) -> Scene:
    """The cluttered scene for ``settings`` (option ``density``; fixed goal)."""
    require_fixed_goal(settings)
    options = scenario_options(settings, OPTIONS)
    density = option_positive("density", options.get("density", str(DENSITY)))
    return make_scene(settings, make_world(density), GOAL, TOLERANCE, MAX_STEPS)


def main(argv: list[str] | None = None) -> int:
    parser = make_parser("cluttered", __doc__, max_steps=MAX_STEPS)
    parser.add_argument("--density", help=f"observed points per square metre of box face (default {DENSITY}, "
                                          "the paper's)")

    def settings(args) -> EpisodeSettings:
        options = (("density", args.density),) if args.density is not None else ()
        return base_settings("cluttered", args, options=options)

    return run_cli(parser, argv, settings)


if __name__ == "__main__":
    from recorder.cli import exit_with

    exit_with(main())
