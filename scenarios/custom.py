"""A user's own world: one obstacle file (mesh or point cloud) and a goal position.

The obstacle is read by ``scenarios.obstacle_file.load_obstacle`` (trimesh: .stl .obj
.ply .off .glb ...; a .ply without faces, a PCL .pcd, .xyz or .npy is a bare point cloud),
its ``--up`` axis turned to +z and shifted by ``--offset``. Mesh surfaces are observed
at ``--density`` points per square metre, by default the confined worlds'
(``scenarios.solids.DENSITY``), at which an opening the robot fits through is wider
than the holes between the samples; a cloud's points are observed as they are, or one per cube of ``--voxel`` m (a dense
scan thinned; the judge keeps every point). The robot's base is
the origin, its first tangent +z (it starts straight up, 2 m per link). A goal that no motion
reaches (beyond the robot's length, inside the obstacle, or too near it for the tip) is warned of.
An obstacle observed at more than ``scenarios.observe.MAX_OBSERVED`` points is refused (coordinates are metres: a
file in millimetres is a million times too large in area).

    python -m scenarios.custom --obstacles part.stl --offset 3,0,2 --goal 4,0,4

Scenario options (kept in the run's settings): obstacles (absolute path),
goal_position, offset, up, density, tolerance, voxel.

The controller is the one every world gets (``ncedf.presets``): with
``--controller ours`` it closes the observed cloud's clusters where every still
one is convex (a closed convex part), and closes the still points on a grid
where one is not.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from recorder.cli import path_text
from scenarios.cli import base_settings, make_parser, run_cli
from scenarios.episode import (EpisodeSettings, GoalWarning, Scene, make_scene, option_positive, option_vector,
                               require_fixed_goal, scenario_options)
from scenarios.observe import MAX_OBSERVED, observed_cloud
from scenarios.obstacle_file import UP, load_obstacle
from scenarios.solids import DENSITY
from scenarios.world import CloudObstacle, World

TOLERANCE = 0.2
MAX_STEPS = 300
OPTIONS = ("obstacles", "goal_position", "offset", "up", "density", "tolerance", "voxel")


def build(settings: EpisodeSettings) -> Scene:
    """The custom scene: options ``obstacles`` and ``goal_position`` required."""
    require_fixed_goal(settings)
    options = scenario_options(settings, OPTIONS)
    for name in ("obstacles", "goal_position"):
        if name not in options:
            raise ValueError(f"the custom scenario needs the option {name!r}")
    goal = option_vector("goal", options["goal_position"])
    offset = option_vector("offset", options.get("offset", "0,0,0"))
    density = option_positive("density", options.get("density", str(DENSITY)))
    tolerance = option_positive("tolerance", options.get("tolerance", str(TOLERANCE)))
    voxel = option_positive("voxel", options["voxel"]) if "voxel" in options else None
    obstacle = load_obstacle(options["obstacles"], offset, options.get("up", "z"))
    if isinstance(obstacle, CloudObstacle):
        world = World(clouds=(obstacle,), density=density, cloud_voxel=voxel)
    elif voxel is not None:
        raise ValueError(f"{options['obstacles']}: --voxel thins a point cloud; a mesh is observed at --density")
    else:
        world = World(meshes=(obstacle,), density=density)
    check_observed_count(obstacle, world, options["obstacles"])
    scene = make_scene(settings, world, goal, tolerance, MAX_STEPS)
    warn_of_the_goal(scene, options["goal_position"])
    return scene


def check_observed_count(obstacle, world: World, named: str) -> None:
    """ValueError where the obstacle would be observed at more than ``MAX_OBSERVED`` points: a cloud's
    own points (or one per voxel), or a mesh's area times the world's density (a file in millimetres
    read as metres is a million times too large)."""
    density = world.density
    if isinstance(obstacle, CloudObstacle):
        count = len(observed_cloud(obstacle.points, world.cloud_voxel))
        if count > MAX_OBSERVED:
            thinned = "" if world.cloud_voxel is None else f" at --voxel {world.cloud_voxel:g}"
            raise ValueError(f"{named}: {count} points{thinned}, more than the {MAX_OBSERVED} a world may be observed "
                             "at: thin the cloud with --voxel V (one point per cube of V m)")
        return
    count = obstacle.area * density  # in floats: a huge density overflows an int
    if count > MAX_OBSERVED:
        raise ValueError(f"{named}: {obstacle.area:.4g} m^2 of surface at {density:g} points per m^2 is {count:.4g} "
                         f"observed points, more than {MAX_OBSERVED}: coordinates are read as metres (is the file "
                         "in millimetres?); else lower --density")


def warn_of_the_goal(scene: Scene, named: str) -> None:
    """Warn of a goal (``named`` as the user gave it) that no motion reaches: inside the (closed)
    obstacle, or nearer to it than the tip's radius less the goal tolerance (the tip's end disk would
    touch it); ``make_scene`` warns of one beyond the robot's length."""
    goal = scene.goal[None]
    if scene.world.clouds:
        inside, near = False, float(np.linalg.norm(np.asarray(scene.world.clouds[0].points) - goal, axis=-1).min())
    else:
        mesh = scene.world.meshes[0]
        inside, near = mesh.closed and bool(mesh.index.inside(goal)[0]), float(mesh.index.distance(goal)[0][0])
    tip = float(np.atleast_1d(scene.spec.radius)[-1])
    if inside:
        warnings.warn(GoalWarning(f"the goal {named} lies inside the obstacle: it cannot be reached"), stacklevel=3)
    elif near + scene.tolerance < tip:
        warnings.warn(GoalWarning(f"the goal {named} lies {near:.2f} m from the obstacle: the robot's tip, of radius "
                                  f"{tip:.2f} m, cannot come within the goal tolerance of {scene.tolerance:.2f} m "
                                  "without touching it"), stacklevel=3)


def main(argv: list[str] | None = None) -> int:
    parser = make_parser("custom", __doc__, max_steps=MAX_STEPS)
    parser.add_argument("--obstacles", required=True, type=path_text, metavar="FILE",
                        help="obstacle mesh (.stl .obj .ply .glb ...) or point cloud (.pcd .ply .xyz .npy), m")
    parser.add_argument("--goal", required=True, metavar="X,Y,Z", help="goal position, m")
    parser.add_argument("--offset", default="0,0,0", metavar="X,Y,Z", help="shift of the obstacle, m (default 0,0,0)")
    parser.add_argument("--up", choices=tuple(UP), default="z",
                        help="the file's up axis, turned to +z before --offset (glTF: y; default z)")
    parser.add_argument("--density", default=str(DENSITY),
                        help=f"observed points per square metre of mesh surface (default {DENSITY})")
    parser.add_argument("--tolerance", default=str(TOLERANCE), help=f"goal tolerance, m (default {TOLERANCE})")
    parser.add_argument("--voxel", metavar="V", help="observe a point cloud one point per cube of V m, for a dense "
                                                     "scan (default: every point)")

    def settings(args) -> EpisodeSettings:
        options = {"obstacles": str(Path(args.obstacles).resolve()), "goal_position": args.goal,
                   "offset": args.offset, "up": args.up, "density": args.density, "tolerance": args.tolerance}
        if args.voxel is not None:
            options["voxel"] = args.voxel
        return base_settings("custom", args, options=tuple(options.items()))

    return run_cli(parser, argv, settings)


if __name__ == "__main__":
    from recorder.cli import exit_with

    exit_with(main())
