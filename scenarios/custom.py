"""A user's own world: obstacle files (meshes or point clouds) and a goal position.

Each obstacle is read by ``scenarios.obstacle_file.load_obstacle`` (trimesh: .stl .obj
.ply .off .glb ...; a .ply without faces, a PCL .pcd, .xyz or .npy is a bare point
cloud), scaled from its ``--units`` to metres, its ``--up`` axis turned to +z (each one
for all files, or one per file) and shifted by ``--offset``. Mesh surfaces are observed
at ``--density`` points per square metre, by default the confined worlds'
(``scenarios.solids.DENSITY``), at which an opening the robot fits through is wider than
the holes between the samples; a cloud's points are observed as they are, or one per
cube of ``--voxel`` m (a dense scan thinned; the judge keeps every point). The robot's
base is the origin, its first tangent +z (it starts straight up, 2 m per link). A goal
that no motion reaches (beyond the robot's length, inside an obstacle, or too near one
for the tip) is warned of. A world observed at more than
``scenarios.observe.MAX_OBSERVED`` points is refused (a file in millimetres read as
metres is a million times too large in area).

    python -m scenarios.custom --obstacles part.stl --offset 3,0,2 --goal 4,0,4
    python -m scenarios.custom --obstacles table.glb scan.pcd --up y z --goal 4,0,1
    python -m scenarios.custom --obstacles bracket_mm.stl --units mm --goal 4,0,4
    python -m scenarios.custom --obstacles wall.stl --goal 4.2,0,3.5 --approach 1,0,0

Scenario options (kept in the run's settings): obstacles (absolute paths joined by
``os.pathsep``), goal_position, approach, offset, up and units (one per file, or one, joined by
commas), density, tolerance, voxel.

The controller is the one every world gets (``ncedf.presets``): with
``--controller ours`` it closes the observed cloud's clusters where every still
one is convex (a closed convex part), and closes the still points on a grid
where one is not.
"""

from __future__ import annotations

import math
import os
import warnings
from pathlib import Path

import numpy as np

from recorder.cli import path_text
from scenarios.cli import base_settings, make_parser, run_cli
from scenarios.episode import (ANGLE_TOLERANCE, EpisodeSettings, GoalWarning, Scene, make_scene, option_positive,
                               option_vector, require_fixed_goal, scenario_options)
from scenarios.observe import MAX_OBSERVED, observed_cloud
from scenarios.obstacle_file import UNITS, UP, load_obstacle
from scenarios.solids import DENSITY
from scenarios.world import CloudObstacle, World

TOLERANCE = 0.2
MAX_STEPS = 300
OPTIONS = ("obstacles", "goal_position", "approach", "offset", "up", "units", "density", "tolerance", "voxel")


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
    if "approach" in options:
        goal = pose_along(goal, option_vector("approach", options["approach"]))
    paths = options["obstacles"].split(os.pathsep)
    frames = list(zip(per_file(options, "up", "z", len(paths)), per_file(options, "units", "m", len(paths))))
    world = load_world(paths, offset, frames, density, voxel)
    scene = make_scene(settings, world, goal, tolerance, MAX_STEPS)
    warn_of_the_goal(scene, options["goal_position"])
    return scene


def pose_along(position, direction) -> np.ndarray:
    """The (4, 4) pose at ``position`` (3,) m whose z axis, the tip's tangent, points along
    ``direction`` (3,): the least rotation from +z (Rodrigues; half a turn about x for -z), the tip
    frame of a robot bent in the plane of +z and the direction; ValueError for a zero direction."""
    norm = float(np.linalg.norm(direction))
    if not norm > 0:
        raise ValueError(f"approach {tuple(direction)} has no direction")
    a, z = np.asarray(direction, np.float64) / norm, np.array([0.0, 0.0, 1.0])
    v, c = np.cross(z, a), float(z @ a)
    cross = np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
    pose = np.eye(4)
    pose[:3, :3] = np.diag([1.0, -1.0, -1.0]) if c < -1.0 + 1e-12 else np.eye(3) + cross + cross @ cross / (1.0 + c)
    pose[:3, 3] = position
    return pose


def per_file(options: dict[str, str], name: str, default: str, files: int) -> list[str]:
    """The option's comma-separated values, one for each of the ``files``: one for every file, or
    one per file; ValueError for another count."""
    values = options.get(name, default).split(",")
    if len(values) not in (1, files):
        raise ValueError(f"{name} {options[name]!r}: {len(values)} values for {files} obstacle files; give one for "
                         "every file or one per file")
    return values * (files // len(values))


def load_world(paths: list[str], offset, frames: list[tuple[str, str]], density: float,
               voxel: float | None) -> World:
    """The world of the obstacle files (``load_obstacle`` with ``offset`` and each file's up axis and
    units, ``frames``), observed at ``density`` (meshes) and ``voxel`` (clouds); ValueError where
    ``voxel`` has no cloud to thin or the world would be observed at more than ``MAX_OBSERVED``
    points (a file in millimetres read as metres is a million times too large in area)."""
    obstacles = [load_obstacle(path, offset, up, units) for path, (up, units) in zip(paths, frames)]
    clouds = tuple(o for o in obstacles if isinstance(o, CloudObstacle))
    world = World(meshes=tuple(o for o in obstacles if not isinstance(o, CloudObstacle)), clouds=clouds,
                  density=density, cloud_voxel=voxel)
    named = ", ".join(paths)
    if voxel is not None and not clouds:
        raise ValueError(f"{named}: --voxel thins a point cloud; a mesh is observed at --density")
    area = sum(mesh.area for mesh in world.meshes)
    if area * density > MAX_OBSERVED:  # in floats: a huge density overflows an int
        raise ValueError(f"{named}: {area:.4g} m^2 of surface at {density:g} points per m^2 is {area * density:.4g} "
                         f"observed points, more than {MAX_OBSERVED}: is a file in millimetres? (give --units mm); "
                         "else lower --density")
    points = sum(len(observed_cloud(cloud.points, voxel)) for cloud in clouds)
    if points + area * density > MAX_OBSERVED:
        thinned = "" if voxel is None else f" at --voxel {voxel:g}"
        raise ValueError(f"{named}: {points} cloud points{thinned} and {area * density:.0f} on the meshes, more than "
                         f"the {MAX_OBSERVED} a world may be observed at: thin the cloud with --voxel V (one point "
                         "per cube of V m)")
    return world


def warn_of_the_goal(scene: Scene, named: str) -> None:
    """Warn of a goal (``named`` as the user gave it) that no motion reaches: inside a (closed)
    obstacle, or nearer to one than the tip's radius less the goal tolerance (the tip's end disk would
    touch it); ``make_scene`` warns of one beyond the robot's length."""
    goal = (scene.goal[:3, 3] if scene.goal.shape == (4, 4) else scene.goal)[None]
    meshes = scene.world.meshes
    inside = [mesh for mesh in meshes if mesh.closed and bool(mesh.index.inside(goal)[0])]
    near = min([float(np.linalg.norm(np.asarray(cloud.points) - goal, axis=-1).min()) for cloud in scene.world.clouds]
               + [float(mesh.index.distance(goal)[0][0]) for mesh in meshes])
    tip = float(np.atleast_1d(scene.spec.radius)[-1])
    if inside:
        warnings.warn(GoalWarning(f"the goal {named} lies inside the obstacle {Path(inside[0].name).name}: it cannot "
                                  "be reached"), stacklevel=3)
    elif near + scene.tolerance < tip:
        warnings.warn(GoalWarning(f"the goal {named} lies {near:.2f} m from the obstacle: the robot's tip, of radius "
                                  f"{tip:.2f} m, cannot come within the goal tolerance of {scene.tolerance:.2f} m "
                                  "without touching it"), stacklevel=3)


def main(argv: list[str] | None = None) -> int:
    parser = make_parser("custom", __doc__, max_steps=MAX_STEPS)
    parser.add_argument("--obstacles", required=True, type=path_text, metavar="FILE", nargs="+",
                        help="obstacle meshes or point clouds, m (one file or more)")
    parser.add_argument("--goal", required=True, metavar="X,Y,Z", help="goal position, m")
    parser.add_argument("--approach", metavar="X,Y,Z",
                        help="the tip's direction at the goal (a pose goal: arrive along it, within "
                             f"{math.degrees(ANGLE_TOLERANCE):g} degrees)")
    parser.add_argument("--offset", default="0,0,0", metavar="X,Y,Z",
                        help="shift of the obstacles, m (default 0,0,0)")
    parser.add_argument("--up", choices=tuple(UP), default=["z"], metavar="AXIS", nargs="+",
                        help=f"up axis turned to +z, of every file or of each: {', '.join(UP)} (glTF: y; "
                             "default z)")
    parser.add_argument("--units", choices=tuple(UNITS), default=["m"], metavar="U", nargs="+",
                        help=f"length unit of every file or each: {', '.join(UNITS)} (default m)")
    parser.add_argument("--density", default=str(DENSITY),
                        help=f"observed points per square metre of mesh surface (default {DENSITY})")
    parser.add_argument("--tolerance", default=str(TOLERANCE), help=f"goal tolerance, m (default {TOLERANCE})")
    parser.add_argument("--voxel", metavar="V", help="observe a point cloud one point per cube of V m, for a dense "
                                                     "scan (default: every point)")

    def settings(args) -> EpisodeSettings:
        paths = [str(Path(path).resolve()) for path in args.obstacles]
        joined = [path for path in paths if os.pathsep in path]
        if joined:
            raise ValueError(f"obstacle file {joined[0]!r}: a path with {os.pathsep!r} cannot be kept in the run's "
                             "settings, which join the files' paths with it; rename it")
        options = {"obstacles": os.pathsep.join(paths), "goal_position": args.goal, "offset": args.offset,
                   "up": ",".join(args.up), "units": ",".join(args.units), "density": args.density,
                   "tolerance": args.tolerance}
        for name in ("voxel", "approach"):
            if getattr(args, name) is not None:
                options[name] = getattr(args, name)
        return base_settings("custom", args, options=tuple(options.items()))

    return run_cli(parser, argv, settings)


if __name__ == "__main__":
    from recorder.cli import exit_with

    exit_with(main())
