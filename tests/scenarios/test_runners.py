"""Scenario runners: a CLI end to end, one-line errors, presets, and the scenes against docs/paper-setups.md."""

import dataclasses
import math
import os
import signal
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import trimesh

from ncedf.geometry import robot_mesh_arrays
from ncedf.grid_model import GridModel, goal_open
from ncedf.presets import BALLS_MARGIN, POINT_BUCKET, Observation, observe, point_capacity, preset
from ncedf.robot import RobotSpec, end_effector_pose
from recorder import inspect as recorder_inspect
from recorder import load_run
from scenarios import charging, cluttered, custom, spheres
from scenarios import episode as episode_mod
from scenarios.cli import summary
from scenarios.episode import Episode, EpisodeResult, EpisodeSettings, describe_world
from scenarios.observe import MAX_OBSERVED, make_observer
from scenarios.truth import true_min_distance
from test_world import box_sdf_np

TINY = ["--links", "4", "--samples", "16", "--horizon", "4", "--max-steps", "2"]


def exit_status(main, argv):
    try:
        return main(argv)
    except SystemExit as exc:  # argparse's own errors
        return exc.code


@pytest.fixture(scope="module")
def cluttered_run(tmp_path_factory):
    folder = tmp_path_factory.mktemp("cluttered")
    status = cluttered.main(TINY + ["--out", str(folder / "rec")])
    return status, folder


def test_cluttered_cli_writes_complete_recordings(cluttered_run, capsys):
    status, folder = cluttered_run
    assert status == 0
    rrd, mcap = load_run(folder / "rec.rrd"), load_run(folder / "rec.mcap")
    for run in (rrd, mcap):
        assert run.complete and run.outcome["outcome"] in ("success", "collision", "stuck")
        assert run.meta["scenario"] == "cluttered" and run.meta["settings"]["samples"] == 16
        assert len(run.metrics) == run.outcome["steps"] + (run.outcome["outcome"] != "collision")
    assert rrd.outcome == mcap.outcome
    assert recorder_inspect.main([str(folder / "rec.rrd"), str(folder / "rec.mcap")]) == 0
    assert "outcome: " in capsys.readouterr().out


def test_existing_recordings_are_kept(cluttered_run, capsys):
    _, folder = cluttered_run
    before = (folder / "rec.mcap").read_bytes()
    assert cluttered.main(TINY + ["--out", str(folder / "rec")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "rec" in err and "overwrite" in err
    assert (folder / "rec.mcap").read_bytes() == before


@pytest.mark.parametrize("signum, status", [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_a_signal_keeps_the_steps_so_far(cluttered_run, capsys, monkeypatch, signum, status):
    _, folder = cluttered_run
    judge = episode_mod.judge_mod.judge_step

    def judge_then_signal(world, spec, arc0, arc1, t0, dt):
        if t0 > 0.5 * dt:  # during step 1
            os.kill(os.getpid(), signum)
        return judge(world, spec, arc0, arc1, t0, dt)

    monkeypatch.setattr(episode_mod.judge_mod, "judge_step", judge_then_signal)
    out = folder / f"stopped-{status}"
    assert cluttered.main(TINY[:-1] + ["5", "--out", str(out)]) == status
    err = [line for line in capsys.readouterr().err.splitlines() if line and not line.startswith("cluttered:")]
    assert len(err) == 1 and "interrupted" in err[0] and signal.Signals(signum).name in err[0]  # the bar aside
    for suffix in (".rrd", ".mcap"):
        run = load_run(out.with_suffix(suffix))
        assert run.complete and run.outcome["outcome"] == "interrupted" and list(run.metrics["step"]) == [0, 1]


@pytest.mark.parametrize("argv, named", [
    (["--links", "0"], "0"),
    (["--shape", "bogus"], "bogus"),
    (["--model", "no/such/model.msgpack"], "no/such/model"),
    (["--controller", "best"], "best"),
    (["--formats", "rrd,png"], "png"),
    (["--links", "four"], "four"),
    (["--mesh-every", "0"], "mesh-every"),
    (["--shape", "exact", "--model", "m.msgpack"], "m.msgpack"),
    (["--density", "0"], "density '0'"),
    (["--density", "many"], "many"),
    (["--density", "1e30"], "at 1e+30 points per m^2"),  # past the observed points' limit, not drawn
])
def test_bad_values_exit_2_with_one_line_and_write_nothing(tmp_path, capsys, argv, named):
    out = tmp_path / "new" / "rec"
    assert exit_status(cluttered.main, argv + ["--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and named in err
    assert not (tmp_path / "new").exists()


def test_custom_runner_names_a_bad_obstacle_file_or_goal(tmp_path, capsys):
    cloud, dense, part = tmp_path / "cloud.npy", tmp_path / "dense.npy", tmp_path / "part_mm.stl"
    np.save(cloud, np.array([[3.0, 0.0, 3.0]]))
    np.save(dense, np.random.default_rng(0).uniform(2.0, 6.0, (MAX_OBSERVED + 1, 3)))
    trimesh.creation.box(extents=(100.0, 100.0, 100.0)).export(part)  # a 10 cm cube in millimetres: 6e4 m^2
    for argv, named in [(["--obstacles", str(tmp_path / "missing.stl"), "--goal", "4,0,4"], "missing.stl"),
                        (["--obstacles", str(cloud), "--goal", "4,0"], "4,0"),
                        (["--obstacles", str(cloud), "--goal", "4,0,4", "--density", "-1"], "-1"),
                        (["--obstacles", str(part), "--goal", "4,0,4"], "millimetres"),
                        (["--obstacles", str(dense), "--goal", "4,0,4"], "thin the cloud with --voxel"),
                        (["--obstacles", str(dense), "--goal", "4,0,4", "--voxel", "1e-3"], "at --voxel 0.001"),
                        (["--obstacles", str(part), "--goal", "4,0,4", "--voxel", "0.1"], "thins a point cloud"),
                        (["--obstacles", str(dense), "--goal", "4,0,4", "--voxel", "0"], "voxel"),
                        (["--obstacles", str(dense), "--goal", "4,0,4", "--voxel", "1e-300"], "too small"),
                        (["--obstacles", str(tmp_path / "a:b.npy"), "--goal", "4,0,4"], "a:b.npy"),
                        (["--obstacles", str(cloud), "--goal", "4,0", "--up=-y"], "4,0")]:  # a negative axis parsed
        assert exit_status(custom.main, argv + ["--out", str(tmp_path / "new" / "rec")]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and named in err
    assert not (tmp_path / "new").exists()
    scene = custom.build(EpisodeSettings("custom", 4, 0, options=(
        ("obstacles", str(part)), ("goal_position", "4,0,4"), ("units", "mm"))))
    np.testing.assert_allclose(scene.world.meshes[0].area, 0.06)  # the 10 cm cube read in millimetres


def test_custom_runner_observes_a_dense_cloud_thinned_and_judges_every_point(tmp_path):
    dense = tmp_path / "scan.npy"
    points = np.random.default_rng(1).uniform((3.0, -1.0, 0.0), (3.2, 1.0, 6.0), (MAX_OBSERVED + 1, 3))
    np.save(dense, points)
    scene = custom.build(EpisodeSettings("custom", 4, 0, options=(
        ("obstacles", str(dense)), ("goal_position", "4,0,4"), ("voxel", "0.25"))))
    assert len(scene.world.clouds[0].points) == len(points)
    observed = make_observer(scene.world, 0).static_points
    assert len(observed) == 8 * 24 and len(observed) == len(np.unique(np.floor(observed / 0.25), axis=0))


def test_custom_runner_takes_several_files_meshes_and_clouds_together(tmp_path, monkeypatch):
    """A table (a closed box, written +y up as glTF says) and a scanned cloud (+z up): both in the
    world, each turned by its own up axis, and in the observation; the goal warned of inside the one
    and near the other; the command's settings name both files and both axes."""
    table, scan = tmp_path / "table.glb", tmp_path / "scan.xyz"
    trimesh.creation.box(bounds=[(2.0, 0.0, -1.0), (3.0, 1.0, 1.0)]).export(table)  # 10 m^2 of surface
    np.savetxt(scan, [[4.0, 0.0, 4.0], [4.0, 0.5, 4.0]])
    options = (("obstacles", os.pathsep.join([str(table), str(scan)])), ("density", "10"), ("tolerance", "0.1"),
               ("up", "y,z"))

    def build(goal: str):
        return custom.build(EpisodeSettings("custom", 4, 0, options=(*options, ("goal_position", goal))))

    scene = build("4,0,2")
    assert len(scene.world.meshes) == 1 and len(scene.world.clouds) == 1
    vertices = scene.world.meshes[0].vertices
    np.testing.assert_allclose([vertices.min(axis=0), vertices.max(axis=0)], [[2, -1, 0], [3, 1, 1]], atol=1e-12)
    np.testing.assert_array_equal(scene.world.clouds[0].points, [[4.0, 0.0, 4.0], [4.0, 0.5, 4.0]])
    assert len(make_observer(scene.world, 0).static_points) == 100 + 2
    with pytest.warns(UserWarning, match="inside the obstacle table.glb"):
        build("2.5,0,0.5")
    with pytest.warns(UserWarning, match="0.05 m from the obstacle"):
        build("4,0.5,4.05")
    with pytest.raises(ValueError, match="2 values for 3 obstacle files"):
        custom.build(EpisodeSettings("custom", 4, 0, options=(
            ("obstacles", os.pathsep.join([str(table), str(scan), str(scan)])), ("up", "y,z"),
            ("goal_position", "4,0,2"))))
    argv = ["--obstacles", str(table), str(scan), "--up", "y", "z", "--goal", "4,0,2", "--voxel", "0.1"]
    kept = []  # the settings the command would run (no episode: its compilation is the suite's cost)
    monkeypatch.setattr(custom, "run_cli", lambda parser, args, make: kept.append(make(parser.parse_args(args))))
    custom.main(argv)
    options = dict(kept[0].options)
    assert (options["obstacles"], options["up"], options["voxel"]) == (os.pathsep.join([str(table), str(scan)]),
                                                                     "y,z", "0.1")
    world = custom.build(kept[0]).world
    assert describe_world(world)["cloud_voxel"] == 0.1 and len(describe_world(world)["meshes"]) == 1


def test_an_approach_makes_a_pose_goal_whose_tangent_points_along_it(tmp_path):
    """The least rotation from +z: for +x the charging port's (a robot bent in the xz-plane); its z
    axis the direction for any other, -z included; the scene judges the pose's approach angle."""
    np.testing.assert_allclose(custom.pose_along((1, 2, 3), (2, 0, 0))[:3, :3], charging.APPROACH_ROTATION, atol=1e-15)
    for direction in [(0, 0, -1), (0, 1, 0), (1, -2, 0.5), (-1, 0, -1e-9)]:
        pose = custom.pose_along((1, 2, 3), direction)
        turn = pose[:3, :3]
        np.testing.assert_allclose(turn[:, 2], np.asarray(direction) / np.linalg.norm(direction), atol=1e-12)
        np.testing.assert_allclose(turn @ turn.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(turn) == pytest.approx(1.0) and list(pose[:3, 3]) == [1, 2, 3]
    with pytest.raises(ValueError, match="no direction"):
        custom.pose_along((1, 2, 3), (0, 0, 0))
    cloud = tmp_path / "cloud.npy"
    np.save(cloud, np.array([[3.0, 0.0, 3.0]]))
    scene = custom.build(EpisodeSettings("custom", 4, 0, options=(
        ("obstacles", str(cloud)), ("goal_position", "4,0,4"), ("approach", "1,0,0"))))
    assert scene.goal.shape == (4, 4) and scene.angle_tolerance == episode_mod.ANGLE_TOLERANCE


def test_custom_runner_warns_of_a_goal_no_motion_reaches(tmp_path):
    """Beyond the robot's length (8 m with 4 links, plus the tolerance), inside a closed mesh, or too near
    a point for the tip's radius (0.2 m) less the tolerance; none for goals that pass each test."""
    cloud, box = tmp_path / "cloud.npy", tmp_path / "box.stl"
    np.save(cloud, np.array([[3.0, 0.0, 3.0]]))
    trimesh.creation.box(extents=(1.0, 1.0, 1.0), transform=trimesh.transformations.translation_matrix(
        (4.0, 0.0, 4.0))).export(box)

    def build(obstacles, goal: str, links: int = 4, tolerance: str = "0.2"):
        return custom.build(EpisodeSettings("custom", links, 0, options=(
            ("obstacles", str(obstacles)), ("goal_position", goal), ("tolerance", tolerance))))

    for obstacles, goal, tolerance, message in [
            (cloud, "0,0,9", "0.2", r"9.00 m from the base, beyond the reach of the 4-link robot \(8 m\): it cannot"),
            (box, "4,0,4", "0.2", "inside the obstacle"),
            (box, "4,0,4.55", "0.1", "0.05 m from the obstacle: the robot's tip, of radius 0.20 m"),
            (cloud, "3,0,3.05", "0.1", "0.05 m from the obstacle")]:
        with pytest.warns(UserWarning, match=message):
            build(obstacles, goal, tolerance=tolerance)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        build(cloud, "0,0,8.1")  # within the tolerance of the tip's farthest reach
        build(cloud, "0,0,9", links=5)
        build(cloud, "3,0,3.05")  # the tip's end 0.2 m off the point is within the tolerance of the goal
        build(box, "4,0,4.75", tolerance="0.1")


def test_the_summary_tells_a_collision_at_the_start_from_one_during_a_step():
    at_start = EpisodeResult("collision", 0, None, -0.2, 0, math.nan, math.nan, 4.0)
    during = dataclasses.replace(at_start, steps=3, first_collision_step=2, solver_ms_mean=50.0, solver_ms_std=1.0)
    assert summary(at_start).splitlines()[0] == ("outcome: collision at the start: the robot's start pose overlaps "
                                                 "an obstacle (0 MPPI steps)")
    assert summary(during).splitlines()[0] == "outcome: collision in step 2 (3 MPPI steps)"


# ---------------------------------------------------------------- presets
def test_presets_follow_paper_setups():
    surfaces, balls = Observation(500), Observation(8, ball_radius=0.7)
    release = {links: preset("release", RobotSpec(links), surfaces) for links in (4, 5, 7)}
    assert [(c.mppi.samples, c.mppi.horizon) for c in release.values()] == [(800, 20), (800, 20), (800, 7)]
    r = release[4].mppi
    assert (r.covariance, release[4].sampling.clip, r.w_goal_terminal, r.w_coll_terminal, r.w_perturbation) == (
        0.1, 0.5, 22.0, 1.1, 0.1)
    assert (r.w_goal, r.w_coll, r.w_state, release[4].temperature.value, r.safety_margin) == (
        12.0, 1.1, 50.0, 0.02, 0.05)
    s = preset("release", RobotSpec(4), balls).mppi
    assert (s.samples, s.horizon, s.safety_margin) == (1000, 12, pytest.approx(0.75))
    p = preset("paper", RobotSpec(7), surfaces)
    assert (p.mppi.samples, p.mppi.horizon, p.mppi.covariance, p.sampling.clip, p.mppi.w_goal_terminal) == (
        800, 20, 0.05, None, 0.0)
    assert p.safety is None and p.model is None and p.recovery is None
    small = preset("paper", RobotSpec(4), balls, samples=16, horizon=3)
    assert (small.mppi.samples, small.mppi.horizon) == (16, 3)
    with pytest.raises(ValueError, match="best"):
        preset("best", RobotSpec(4), surfaces)


def test_point_capacity_rounds_up_to_the_bucket():
    assert [point_capacity(n) for n in (0, 1, POINT_BUCKET, POINT_BUCKET + 1)] == [
        POINT_BUCKET, POINT_BUCKET, POINT_BUCKET, 2 * POINT_BUCKET]


# ---------------------------------------------------------------- scenes
def test_cluttered_scene_is_the_papers():
    scene = Episode(EpisodeSettings("cluttered", 7, 0)).scene
    world = scene.world
    paper_boxes = [((2.5, 0, 5), (1, 4.8, 3)), ((2.5, 0, 0), (1, 5, 2)), ((5.3, 0, 2), (2, 5, 1))]
    assert [(b.centre, b.size) for b in world.boxes] == paper_boxes
    assert [(s.centre, s.velocity) for s in world.spheres] == [((4, -4.5, 3.8), (0, 1, 0)), ((4, 0, 2.2), (0, 0, -0.8))]
    assert [s.radius for s in world.spheres] == [0.5, 0.5] and all(s.half_period == 5.0 for s in world.spheres)
    area = sum(2 * (x * y + y * z + x * z) for _, (x, y, z) in paper_boxes)
    assert abs(scene.observer.n_points - (4.0 * area + 60)) < 0.1 * (4.0 * area + 60)  # about 500
    assert scene.config.mppi.max_points >= scene.observer.n_points and scene.config.mppi.horizon == 7
    assert (tuple(scene.goal), scene.tolerance, scene.max_steps) == ((4.8, 0.0, 3.6), 0.4, 300)


@pytest.mark.parametrize("density", [1.0, 16.0])
def test_cluttered_density_option_sets_the_points_per_face(density):
    scene = Episode(EpisodeSettings("cluttered", 4, 0, options=(("density", str(density)),))).scene
    assert scene.world.density == density
    faces = [a for _, (x, y, z) in cluttered.BOXES for a in (x * y, x * y, y * z, y * z, x * z, x * z)]
    expected = sum(round(density * a) for a in faces) + len(cluttered.SPHERES) * cluttered.SPHERE_POINTS
    assert scene.observer.n_points == expected
    assert scene.config.mppi.max_points >= expected
    with pytest.raises(ValueError, match=r"\['spacing'\].*known: density"):
        Episode(EpisodeSettings("cluttered", 4, 0, options=(("spacing", "1"),)))


@pytest.mark.parametrize("env_seed", [0, 1, 2])
@pytest.mark.parametrize("goal", ["fixed", "random"])
def test_spheres_environments_are_accepted_and_deterministic(env_seed, goal):
    spec = RobotSpec(4)
    world, target, attempts = spheres.make_environment(env_seed, spec, goal)
    again, target_again, _ = spheres.make_environment(env_seed, spec, goal)
    assert again == world and np.array_equal(target, target_again) and attempts >= 1
    centres = np.array([s.centre for s in world.spheres])
    velocities = np.array([s.velocity for s in world.spheres])
    assert len(centres) == 8 and all(s.radius == 0.7 and s.half_period == 2.0 for s in world.spheres)
    assert np.all(centres >= [-4, -4, -1]) and np.all(centres <= [4, 4, 6])
    assert np.all((velocities >= 0) & (velocities < 1))
    gaps = np.linalg.norm(centres[:, None] - centres[None], axis=-1) + 10 * np.eye(8)
    assert gaps.min() >= 1.5
    assert np.linalg.norm(centres - target, axis=1).min() >= 2.0
    # exact distance from the straight robot to the sphere surfaces (the judge's geometry)
    assert true_min_distance(world, spec, np.asarray(spec.straight_state()), 0.0) > 0.1
    if goal == "fixed":
        assert tuple(target) == (4.0, 0.0, 4.0)
    else:
        assert np.linalg.norm(target) <= 2.0 * spec.n_links  # the tip of some configuration
    assert world.observe == "centres" and world.margin_extra == 0.7


def test_spheres_scene_observes_centres_with_a_wider_margin():
    scene = Episode(EpisodeSettings("spheres", 4, 0, env_seed=5, shape="exact")).scene
    assert scene.observer.n_points == 8 and scene.observer.observe(0.0).shape == (8, 3)
    assert (scene.config.mppi.samples, scene.config.mppi.horizon) == (1000, 12)
    assert scene.config.mppi.safety_margin == pytest.approx(BALLS_MARGIN + 0.7)  # the radius on top of ours's margin
    assert (scene.tolerance, scene.max_steps) == (0.2, 200)


@pytest.mark.parametrize("env_seed", [0, 1, 7])
def test_charging_wall_leaves_exactly_the_port_open(env_seed):
    world, port = charging.make_world(env_seed)
    assert port[0] == 5.0 and -3 <= port[1] <= 3 and 1 <= port[2] <= 5
    lo = np.array([c - s / 2 for c, s in zip((5.0, 0.0, 3.0), (1.0, 7.0, 6.0))])
    hi = lo + np.array([1.0, 7.0, 6.0])
    boxes = [(np.array(b.centre) - np.array(b.size) / 2, np.array(b.centre) + np.array(b.size) / 2)
             for b in world.boxes]
    assert sum(np.prod(b - a) for a, b in boxes) == pytest.approx(1 * 7 * 6 - 1)
    samples = lo + (hi - lo) * np.random.default_rng(env_seed).random((4000, 3))
    inside = np.stack([np.all((samples > a) & (samples < b), axis=1) for a, b in boxes]).sum(axis=0)
    in_port = np.all(np.abs(samples[:, 1:] - port[1:]) < 0.5, axis=1)
    np.testing.assert_array_equal(inside, ~in_port)  # each wall point in exactly one box, none in the port
    assert len(world.spheres) == 8 and all(s.radius == 0.5 and s.half_period == 2.0 for s in world.spheres)
    assert world.density == 5.0


def test_charging_goal_is_a_pose_approaching_along_x():
    scene = Episode(EpisodeSettings("charging", 4, 0, env_seed=3, shape="exact")).scene
    goal = scene.goal
    assert goal.shape == (4, 4) and scene.angle_tolerance is not None
    np.testing.assert_allclose(goal[:3, 2], [1.0, 0.0, 0.0])
    np.testing.assert_allclose(goal[:3, :3] @ goal[:3, :3].T, np.eye(3), atol=1e-12)
    assert np.linalg.det(goal[:3, :3]) == pytest.approx(1.0)
    np.testing.assert_allclose(goal[:3, 3], charging.port_position(3))
    assert scene.config.mppi.max_points >= scene.observer.n_points


def _model_after_two_observations(settings: EpisodeSettings):
    """The obstacle model of ``ours`` in the scene of ``settings`` at its second step (the first that
    tells static points from moving ones), and the scene."""
    episode = Episode(dataclasses.replace(settings, controller="ours"))
    scene, controller = episode.scene, episode.mppi
    if scene.config.model is None:
        return None, scene
    dt = scene.config.mppi.dt
    before, now = (controller.pad_points(scene.observer.observe(t)) for t in (0.0, dt))
    state = controller.init(jax.random.PRNGKey(0))._replace(previous=before[0], previous_mask=before[1])
    return controller.fit_model(state, *now, controller.check_goal(scene.goal))[0], scene


def test_ours_models_what_it_observes_whatever_the_world(tmp_path):
    import trimesh

    trimesh.creation.box(extents=(1.0, 3.0, 2.0)).export(tmp_path / "box.stl")
    custom = EpisodeSettings("custom", 4, 0, shape="exact", options=(
        ("goal_position", "4,0,4"), ("obstacles", str(tmp_path / "box.stl")), ("offset", "3,0,3")))
    # A closed box: one static polytope, the box itself (its faces are sampled); ours keeps its model.
    box, _ = _model_after_two_observations(custom)
    static = box.present & ~np.any(box.velocity != 0, axis=-1)
    assert int(np.sum(static)) == 1 and int(box.left_out) == 0
    np.testing.assert_allclose(box.lower[static][0], [2.5, -1.5, 2.0], atol=0.05)
    np.testing.assert_allclose(box.upper[static][0], [3.5, 1.5, 4.0], atol=0.05)
    # The charging wall with its port is not convex: the convex model would close the port, so ours
    # closes the wall on a grid that keeps a way to the port open: the robot's radius of room from the
    # port's centre out to the grid's border.
    fitted, scene = _model_after_two_observations(EpisodeSettings("charging", 4, 0, shape="exact"))
    grid = fitted.grid
    dt = scene.config.mppi.dt
    seen = observe(scene.observer.observe(0.0), scene.observer.observe(dt), dt)
    assert not seen.convex and isinstance(scene.config.model, GridModel)
    cell = tuple(np.rint((scene.goal[:3, 3] - grid.origin) / grid.spacing).astype(int))
    assert goal_open(grid.array(), cell, scene.spec.radius)
    # Balls observed by their centres: no model, the racing stages.
    balls, scene = _model_after_two_observations(EpisodeSettings("spheres", 4, 0, shape="exact"))
    assert balls is None and scene.config.safety.sweep_first


@pytest.mark.parametrize("links, env_seed", [(4, 0), (5, 8)])
def test_cluttered_random_goal_is_reachable_behind_the_boxes_and_clear_of_them(links, env_seed):
    spec = RobotSpec(links)
    goal, arc, attempts = cluttered.random_goal(env_seed, spec)
    again, arc_again, attempts_again = cluttered.random_goal(env_seed, spec)
    np.testing.assert_array_equal(goal, again)
    np.testing.assert_array_equal(arc, arc_again)
    assert attempts == attempts_again >= 1
    assert not np.allclose(goal, cluttered.random_goal(env_seed + 1, spec)[0])
    assert goal[0] >= cluttered.RANDOM_GOAL_MIN_X and goal[2] >= cluttered.RANDOM_GOAL_MIN_Z
    assert np.all((arc >= spec.l_min) & (arc <= spec.l_max))
    np.testing.assert_allclose(goal, np.asarray(end_effector_pose(jnp.asarray(arc), spec))[:3, 3], atol=1e-6)
    # The configuration's surface (its mesh vertices) against the boxes' closed-form signed distance.
    vertices, _ = robot_mesh_arrays(jnp.asarray(arc), spec)
    vertices = np.asarray(vertices, np.float64)
    clearance = min(box_sdf_np(vertices, c, size).min() for c, size in cluttered.BOXES)
    assert clearance >= cluttered.RANDOM_GOAL_CLEARANCE - 1e-5
    scene = Episode(EpisodeSettings("cluttered", links, 0, env_seed=env_seed, goal="random", shape="exact")).scene
    np.testing.assert_array_equal(scene.goal, goal)
    assert scene.info["goal_attempts"] == attempts
    assert not np.allclose(goal, cluttered.GOAL)


def test_scenarios_refuse_settings_they_do_not_use():
    with pytest.raises(ValueError, match="random"):
        Episode(EpisodeSettings("charging", 4, 0, goal="random"))
    with pytest.raises(ValueError, match="options"):
        Episode(EpisodeSettings("charging", 4, 0, options=(("x", "1"),)))
    with pytest.raises(ValueError, match="obstacles"):
        Episode(dataclasses.replace(EpisodeSettings("custom", 4, 0), options=(("goal_position", "1,2,3"),)))


def test_a_goal_position_in_the_cluttered_scene_and_among_the_spheres():
    goal = (4.5, 1.0, 3.0)
    scene = Episode(EpisodeSettings("cluttered", 4, 0, goal="4.5,1,3", shape="exact")).scene
    np.testing.assert_array_equal(scene.goal, goal)
    assert scene.world == cluttered.make_world()  # the paper's world, another goal
    spec = RobotSpec(4)
    world, target, _ = spheres.make_environment(3, spec, "-3,2,1")
    np.testing.assert_array_equal(target, (-3.0, 2.0, 1.0))
    centres = np.array([s.centre for s in world.spheres])
    assert np.linalg.norm(centres - target, axis=1).min() >= spheres.GOAL_CLEARANCE  # drawn around it


@pytest.mark.parametrize("goal, message", [
    ("2.5,0,5", r"goal \(2.5, 0.0, 5.0\) lies inside the box at \(2.5, 0.0, 5.0\)"),  # the upper box's centre
    ("5.3,2.4,2.4", "lies inside the box at \\(5.3, 0.0, 2.0\\)"),  # just inside a corner of the right box
    ("0,0,8.01", r"8.01 m from the base, beyond the reach of the 4-link robot \(8 m\)")])
def test_a_goal_position_inside_a_box_or_out_of_reach_is_refused(goal, message, capsys):
    with pytest.raises(ValueError, match=message):
        Episode(EpisodeSettings("cluttered", 4, 0, goal=goal, shape="exact"))
    assert cluttered.main(["--goal", goal, "--out", "unused", "--shape", "exact"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: goal") and err.count("\n") == 1


def test_a_scenarios_own_goal_beyond_a_short_robots_reach_is_warned_of():
    with pytest.warns(UserWarning, match=r"beyond the reach of the 1-link robot \(2 m\): it cannot be reached"):
        Episode(EpisodeSettings("cluttered", 1, 0, shape="exact"))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        Episode(EpisodeSettings("cluttered", 4, 0, shape="exact"))


def test_a_goal_position_on_a_box_face_is_accepted():
    Episode(EpisodeSettings("cluttered", 4, 0, goal="3,0,5", shape="exact"))  # the upper box's back face
    with pytest.raises(ValueError, match="beyond the reach"):
        spheres.make_environment(0, RobotSpec(4), "0,0,-8.5")


def test_a_goal_position_with_a_negative_x_on_the_command_line(capsys):
    assert spheres.main(["--goal=-1,2,9", "--out", "unused", "--shape", "exact"]) == 2  # as --help writes it
    assert "goal (-1.0, 2.0, 9.0) is 9.27 m from the base" in capsys.readouterr().err
