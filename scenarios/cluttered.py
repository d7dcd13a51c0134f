"""The cluttered scene (paper Sec. VI-D, Table IV, Figs. 5-7).

Three static boxes and two spheres moving back and forth, all observed as
points on their surfaces (4 points per square metre on the box faces, 30 on
each sphere: about 500). The end effector must reach (4.8, 0, 3.6) within
0.4 m in 300 steps (15 s). The paper reports the goal reached at step 158,
82 and 43 for 4, 5 and 7 links.

    python -m scenarios.cluttered --links 7

With ``--goal random`` the goal is instead the end effector of a random
configuration of the robot (arc lengths uniform in their limits, drawn from
``env_seed``) that keeps at least ``RANDOM_GOAL_CLEARANCE`` from the boxes and
puts the end effector behind them, as the paper's goal is (x >=
``RANDOM_GOAL_MIN_X``, z >= ``RANDOM_GOAL_MIN_Z``): other goals in the same world.
With ``--goal X,Y,Z`` the goal is that position, m (outside the boxes, within the
robot's length of its base; ``--goal=-1,2,3`` when X is negative).

Writes recording.rrd and recording.mcap (replay: ``rerun recording.rrd``).

Scenario option (kept in the run's settings when given): density, the observed
points per square metre of box face (``--density 16``; sweeps: ``--option
density=16``). The paper's 4 leaves holes up to 0.8 m across in the cloud.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from ncedf.robot import RobotSpec, end_effector_pose, sample_arc_lengths
from scenarios.cli import base_settings, make_parser, run_cli
from scenarios.episode import (DRAW_ATTEMPTS, EpisodeSettings, Scene, check_reach, goal_position, make_scene,
                               option_positive, scenario_options, scene_robot)
from scenarios.box_distance import box_sdf
from scenarios.truth import true_distances_batch
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
#: ``--goal random``: the configuration's least exact distance to the boxes, m ...
RANDOM_GOAL_CLEARANCE = 0.3
#: ... and the end effector's least x and z, m (behind the boxes, above the lower one).
RANDOM_GOAL_MIN_X = 3.5
RANDOM_GOAL_MIN_Z = 0.5
#: ``--goal random``'s attempts drawn at once (a divisor of ``DRAW_ATTEMPTS``).
GOAL_DRAWS = 250


def make_boxes() -> tuple[Box, ...]:
    """The static boxes of ``BOXES``."""
    return tuple(Box(centre, size) for centre, size in BOXES)


def make_world(density: float = DENSITY) -> World:
    """The paper's cluttered world, its box faces observed at ``density`` points per m^2."""
    return World(
        spheres=tuple(MovingSphere(centre, SPHERE_RADIUS, velocity, HALF_PERIOD) for centre, velocity in SPHERES),
        boxes=make_boxes(),
        density=density,
        sphere_points=SPHERE_POINTS,
        observe="surface",
    )


def random_goal(env_seed: int, spec: RobotSpec) -> tuple[np.ndarray, np.ndarray, int]:
    """The ``--goal random`` goal of ``env_seed`` (module docstring): (end effector position (3,) m,
    its configuration's arc lengths (M, 3) m, attempts used). Attempt ``i`` draws from
    ``fold_in(PRNGKey(env_seed), i)``."""
    boxes = World(boxes=make_boxes())
    base = jax.random.PRNGKey(env_seed)
    for start in range(0, DRAW_ATTEMPTS, GOAL_DRAWS):
        arcs, tips = (np.asarray(x) for x in _goal_draws(base, start, spec))
        tips = tips.astype(np.float64)
        behind = np.flatnonzero((tips[:, 0] >= RANDOM_GOAL_MIN_X) & (tips[:, 2] >= RANDOM_GOAL_MIN_Z))
        if len(behind):
            clear = true_distances_batch(boxes, spec, arcs[behind], np.zeros(len(behind))).min(axis=1)
            found = behind[clear >= RANDOM_GOAL_CLEARANCE]
            if len(found):  # drawn again alone: vmapped, the draw and the kinematics round differently
                attempt = start + int(found[0])
                arc = np.asarray(sample_arc_lengths(jax.random.fold_in(base, attempt), spec, (spec.n_links,)),
                                 np.float32)
                return np.asarray(end_effector_pose(arc, spec)[:3, 3], np.float64), arc, attempt + 1
    raise ValueError(f"no random goal for env_seed {env_seed} in {DRAW_ATTEMPTS} attempts")


@functools.partial(jax.jit, static_argnums=2)
def _goal_draws(base, start, spec: RobotSpec) -> tuple[jnp.ndarray, jnp.ndarray]:
    """Attempts ``start`` .. ``start + GOAL_DRAWS - 1`` of :func:`random_goal`: their states (GOAL_DRAWS, M, 3) m
    and end-effector positions (GOAL_DRAWS, 3) m."""
    keys = jax.vmap(lambda i: jax.random.fold_in(base, i))(start + jnp.arange(GOAL_DRAWS))
    arcs = jax.vmap(lambda k: sample_arc_lengths(k, spec, (spec.n_links,)))(keys)
    return arcs, end_effector_pose(arcs, spec)[:, :3, 3]


def check_goal(position, spec: RobotSpec) -> None:
    """ValueError when a goal position (3,) m lies inside a box or beyond the robot's reach."""
    for box in make_boxes():
        inside, _ = box_sdf(jnp.asarray(position), jnp.asarray(box.centre), 0.5 * jnp.asarray(box.size))
        if float(inside) < 0:
            raise ValueError(f"goal {tuple(float(v) for v in position)} lies inside the box at {box.centre} "
                             f"(size {box.size})")
    check_reach(position, spec)


def build(settings: EpisodeSettings) -> Scene:
    """The cluttered scene for ``settings`` (option ``density``; the paper's goal, a random one or a position)."""
    options = scenario_options(settings, OPTIONS)
    density = option_positive("density", options.get("density", str(DENSITY)))
    spec = scene_robot(settings)
    goal, info = goal_position(settings.goal), {}
    if goal is not None:
        check_goal(goal, spec)
    elif settings.goal == "random":
        goal, _, info["goal_attempts"] = random_goal(settings.env_seed, spec)
    else:
        goal = GOAL
    return make_scene(settings, make_world(density), goal, TOLERANCE, MAX_STEPS, **info)


def main(argv: list[str] | None = None) -> int:
    parser = make_parser("cluttered", __doc__, max_steps=MAX_STEPS)
    parser.add_argument("--density", help=f"observed points per square metre of box face (default {DENSITY}, "
                                          "the paper's)")
    parser.add_argument("--goal", default="fixed", metavar="GOAL",
                        help=f"fixed (the paper's {GOAL}, default), random (behind the boxes, from --env-seed) "
                             "or X,Y,Z in m")

    def settings(args) -> EpisodeSettings:
        options = (("density", args.density),) if args.density is not None else ()
        return base_settings("cluttered", args, goal=args.goal, options=options)

    return run_cli(parser, argv, settings)


if __name__ == "__main__":
    from recorder.cli import exit_with

    exit_with(main())
