"""Episodes: outcomes against closed-form truths, determinism, recorded settings, interruption.

Every episode here is a custom world read from a .npy cloud of 24 points and a
4-link robot with 16 rollouts over a 4-step horizon, so all share one compiled
controller and one compiled judge.
"""

import dataclasses
import math
import os
import signal
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

from ncedf.broad_phase import BroadPhase
from ncedf.controller import config_from_dict
from recorder import load_run, schema
from scenarios import episode as episode_mod
from scenarios.episode import Episode, EpisodeSettings, episode_name, goal_errors, goal_position, run_episode

SMALL = dict(samples=16, horizon=4)
LINKS = 4
START_TIP = np.array([0.0, 0.0, 2.0 * LINKS])  # straight robot, 2 m links
FAR = [[30.0, 30.0, 30.0]]
CLOUD_POINTS = 24  # every cloud the same size: one compiled judge for all


def settings_for(cloud_file, goal, max_steps, seed=0, tolerance="0.2"):
    options = {"obstacles": str(cloud_file), "goal_position": ",".join(str(float(v)) for v in goal),
               "tolerance": tolerance}
    return EpisodeSettings("custom", LINKS, seed, max_steps=max_steps, options=tuple(options.items()), **SMALL)


@pytest.fixture(scope="module")
def clouds(tmp_path_factory):
    folder = tmp_path_factory.mktemp("clouds")
    rng = np.random.default_rng(0)
    ball = rng.normal(size=(CLOUD_POINTS, 3))
    ball = np.array([1.0, 0.0, 6.0]) + 0.3 * ball / np.linalg.norm(ball, axis=1, keepdims=True)
    far = np.array(FAR) + rng.random((CLOUD_POINTS, 3))
    overlap = far.copy()
    overlap[0] = [0.0, 0.0, 3.0]  # on link 2's backbone: one radius deep
    files = {"far": far, "overlap": overlap, "ball": ball}
    paths = {}
    for name, points in files.items():
        paths[name] = folder / f"{name}.npy"
        np.save(paths[name], points)
    return paths


@pytest.fixture(scope="module")
def recordings(tmp_path_factory):
    return tmp_path_factory.mktemp("episodes")


def read(result):
    (path,) = [p for p in result.paths if p.endswith(".mcap")]
    run = load_run(path)
    assert run.complete
    return run


def log_lines(result) -> list[str]:
    """The text of the recording's log messages (foxglove.Log on /log), in order."""
    (path,) = [p for p in result.paths if p.endswith(".mcap")]
    decoder = DecoderFactory()
    with open(path, "rb") as f:
        return [decoder.decoder_for(channel.message_encoding, schema_)(message.data).message
                for schema_, channel, message in make_reader(f).iter_messages(topics=[schema.LOG])]


def test_overlap_at_start_is_a_collision_at_step_0(clouds, recordings):
    result = run_episode(settings_for(clouds["overlap"], (3.0, 0.0, 6.0), 5), out=recordings / "overlap",
                         formats=("mcap",))
    assert (result.outcome, result.first_collision_step, result.steps) == ("collision", 0, 0)
    run = read(result)
    assert run.outcome["outcome"] == "collision" and run.outcome["first_collision_step"] == 0
    assert len(run.metrics) == 1
    # a point on the backbone of a straight link lies one radius deep
    assert run.metrics["true_min_distance"].iloc[0] == pytest.approx(-0.2, abs=1e-5)
    assert run.outcome["min_true_distance"] == pytest.approx(-0.2, abs=1e-5)
    assert log_lines(result) == ["collision during step 0: exact distance -0.200 m"]


def test_goal_near_the_start_is_reached(clouds, recordings):
    goal = START_TIP + np.array([0.3, 0.0, -0.02])
    result = run_episode(settings_for(clouds["far"], goal, 12), out=recordings / "near", formats=("mcap",))
    run = read(result)
    tips = run.state[["ee_x", "ee_y", "ee_z"]].to_numpy()
    distances = np.linalg.norm(tips - goal, axis=1)
    np.testing.assert_allclose(run.metrics["goal_distance"], distances, atol=1e-6)
    assert result.outcome == "success" and run.outcome["outcome"] == "success"
    first = int(np.argmax(distances <= 0.2))
    assert distances[first] <= 0.2 and np.all(distances[:first] > 0.2)
    assert result.reach_step == run.outcome["reach_step"] == first == result.steps > 0
    assert len(run.metrics) == first + 1  # the last row is the reaching state
    assert math.isnan(run.metrics["solver_ms"].iloc[-1]) and np.all(run.metrics["solver_ms"].iloc[:-1] > 0)
    assert log_lines(result)[-1] == f"goal reached at step {first}, {distances[first]:.3f} m from it"


def test_goal_at_the_start_is_reached_at_step_0(clouds):
    result = run_episode(settings_for(clouds["far"], START_TIP, 5))
    assert (result.outcome, result.reach_step, result.steps) == ("success", 0, 0)
    assert result.final_goal_distance < 1e-5


def test_unreachable_goal_is_stuck(clouds, recordings):
    goal = (0.0, 0.0, 20.0)  # the tip stays within n L = 8 m of the base: >= 12 m away
    with pytest.warns(UserWarning, match="cannot be reached"):
        result = run_episode(settings_for(clouds["far"], goal, 3), out=recordings / "stuck", formats=("mcap",))
    run = read(result)
    assert (result.outcome, result.steps, result.reach_step) == ("stuck", 3, None)
    assert run.outcome["outcome"] == "stuck" and run.outcome["steps"] == 3
    assert list(run.metrics["step"]) == [0, 1, 2, 3]
    assert np.all(run.metrics["goal_distance"] >= 20.0 - 2.0 * LINKS)
    last = run.metrics["goal_distance"].iloc[-1]
    assert log_lines(result)[-1] == f"goal not reached in 3 steps: {last:.3f} m from it"


@pytest.fixture(scope="module")
def twice(clouds, recordings):
    settings = settings_for(clouds["ball"], (2.0, 0.0, 6.5), 5, seed=3)
    return settings, [run_episode(settings, out=recordings / f"ball-{i}", formats=("mcap",)) for i in range(2)]


def test_same_settings_give_the_same_metrics_and_outcome(twice):
    _, results = twice
    first, second = (read(r) for r in results)
    assert first.outcome == second.outcome
    assert len(first.metrics) == 6
    columns = [c for c in first.metrics.columns if c != "solver_ms"]
    pd.testing.assert_frame_equal(first.metrics[columns], second.metrics[columns])
    pd.testing.assert_frame_equal(first.state, second.state)
    strip = dict(solver_ms_mean=0.0, solver_ms_std=0.0, paths=())
    assert dataclasses.replace(results[0], **strip) == dataclasses.replace(results[1], **strip)


def test_recorded_settings_rebuild_the_episode(twice):
    settings, results = twice
    run = read(results[0])
    assert EpisodeSettings.from_dict(run.meta["settings"]) == settings
    assert config_from_dict(run.meta["mppi"]) == Episode(settings).scene.config
    assert run.meta["model"]["id"] and run.meta["model"]["metrics"]["mae"] > 0
    assert run.meta["world"]["clouds"][0]["points"] == CLOUD_POINTS == run.meta["observed_points"]
    assert run.meta["versions"]["jax"]
    assert run.outcome["min_true_distance"] == pytest.approx(run.metrics["true_min_distance"].min())


def test_a_signal_keeps_the_recorded_steps(clouds, recordings, monkeypatch):
    judge = episode_mod.judge_mod.judge_step

    def judge_then_signal(world, spec, arc0, arc1, t0, dt):
        if t0 > 1.5 * dt:  # during step 2
            os.kill(os.getpid(), signal.SIGTERM)
        return judge(world, spec, arc0, arc1, t0, dt)

    monkeypatch.setattr(episode_mod.judge_mod, "judge_step", judge_then_signal)
    before = signal.getsignal(signal.SIGTERM)
    with pytest.warns(UserWarning, match="cannot be reached"):  # a goal out of reach: the episode runs on
        result = run_episode(settings_for(clouds["far"], (0.0, 0.0, 20.0), 6), out=recordings / "signal",
                             formats=("mcap",))
    assert (result.outcome, result.signal, result.steps) == ("interrupted", "SIGTERM", 3)
    run = read(result)
    assert run.outcome["outcome"] == "interrupted" and list(run.metrics["step"]) == [0, 1, 2]
    assert signal.getsignal(signal.SIGTERM) is before


def test_settings_validate_and_round_trip():
    s = EpisodeSettings("spheres", 4, 1, env_seed=2, options=(("b", "2"), ("a", "1")))
    assert s.options == (("a", "1"), ("b", "2"))
    assert EpisodeSettings.from_dict(s.to_dict()) == s
    for bad, text in [(dict(links=0), "links"), (dict(scenario="moon"), "moon"), (dict(seed=-1), "seed"),
                      (dict(controller="best"), "best"), (dict(model=""), "model"),
                      (dict(goal="north"), "north"), (dict(samples=0), "samples"),
                      (dict(options=(("a", "1"), ("a", "2"))), "twice")]:
        with pytest.raises(ValueError, match=text):
            dataclasses.replace(s, **bad)
    with pytest.raises(ValueError, match="colour"):
        EpisodeSettings.from_dict({**s.to_dict(), "colour": "red"})


def test_a_goal_position_is_kept_as_floats_and_bad_ones_are_named():
    s = EpisodeSettings("cluttered", 4, 0, goal=" 4.5, 1,3e0")
    assert s.goal == "4.5,1.0,3.0" and goal_position(s.goal) == (4.5, 1.0, 3.0)
    assert EpisodeSettings.from_dict(s.to_dict()) == s
    assert episode_name(s) == episode_name(dataclasses.replace(s, goal="4.50,1,3"))
    assert episode_name(s) != episode_name(dataclasses.replace(s, goal="4.5,1,3.1"))
    assert goal_position("fixed") is None and goal_position("random") is None
    for bad in ("4,5", "1,2,3,4", "1,nan,2", "x,y,z", "", 5):
        with pytest.raises(ValueError, match="fixed, random or a position X,Y,Z"):
            EpisodeSettings("cluttered", 4, 0, goal=bad)


def test_episode_names_are_unique_and_file_safe():
    base = EpisodeSettings("cluttered", 4, 0, shape="pointcloud:1000")
    variants = [base, dataclasses.replace(base, seed=1), dataclasses.replace(base, samples=100),
                dataclasses.replace(base, shape="exact"), dataclasses.replace(base, env_seed=1),
                dataclasses.replace(base, controller="paper")]
    names = [episode_name(v) for v in variants]
    assert len(set(names)) == len(names)
    assert all(n.replace("_", "").replace("-", "").isalnum() for n in names)
    assert episode_name(base) == episode_name(EpisodeSettings.from_dict(base.to_dict()))


def test_goal_errors_of_a_pose_goal():
    goal = np.eye(4)
    goal[:3, :3] = [[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]]  # approach axis +x
    goal[:3, 3] = [5.0, 1.0, 3.0]
    tip = np.eye(4)  # approach axis +z: 90 degrees off
    tip[:3, 3] = [5.0, 1.0, 3.3]
    distance, angle = goal_errors(tip, goal)
    assert distance == pytest.approx(0.3) and angle == pytest.approx(math.pi / 2)
    assert goal_errors(goal, goal) == pytest.approx((0.0, 0.0))
    assert goal_errors(tip, goal[:3, 3]) == (pytest.approx(0.3), None)


@pytest.mark.parametrize("path", sorted((Path(__file__).parents[2] / "results" / "closed_loop").glob("*.mcap")))
def test_recordings_made_before_the_stages_rebuild_their_episode(path):
    """The committed recordings hold the flat controller settings of their day; read back, they are
    the controller that their settings build today, with the broad phase's sizes of then (12 pairs per
    state, 2 capsules per link), the route's check step of then (0.01 m), every plan's settings the
    first's (growth 1) and no mount."""
    run = load_run(path)
    assert "safety_check" in run.meta["mppi"]  # the flat form
    settings = EpisodeSettings.from_dict(run.meta["settings"])
    today = Episode(settings).scene.config
    recovery = dataclasses.replace(today.recovery, route=dataclasses.replace(today.recovery.route, check_step=0.01),
                                   growth=1.0)
    then = dataclasses.replace(today, broad_phase=BroadPhase(k2=12, capsule_segments=2), recovery=recovery,
                               mount=None)
    assert config_from_dict(run.meta["mppi"]) == then


def test_removed_experiments_in_old_settings_are_named():
    with pytest.raises(ValueError, match="predict_motion"):
        config_from_dict({"samples": 8, "temperature": 0.02, "predict_motion": True})
    with pytest.raises(ValueError, match="unknown controller settings"):
        config_from_dict({"samples": 8, "temperature": 0.02, "wobble": 1})


def test_a_half_size_robot_in_the_half_size_scene_runs_the_same_episode_at_half_size(clouds, recordings, tmp_path):
    from ncedf.model import load_model, save_model
    from ncedf.robot import RobotSpec

    model = load_model()
    half_robot = RobotSpec(1, 1.0, 0.1, 0.8, 1.2)
    save_model(tmp_path / "half", model.params, model.config, half_robot, {},
               tuple(tuple(0.5 * v for v in corner) for corner in model.domain))
    full = settings_for(clouds["ball"], (2.0, 0.0, 6.5), 4, seed=5)
    half = dataclasses.replace(full, model=str(tmp_path / "half"), options=full.options + (("scale", "0.5"),))
    runs = [read(run_episode(s, out=recordings / name, formats=("mcap",)))
            for s, name in ((full, "full"), (half, "half"))]
    assert runs[1].meta["robot"]["length"] == 1.0 and runs[1].meta["goal"] == [1.0, 0.0, 3.25]
    for column in ("goal_distance", "true_min_distance", "predicted_min_distance"):
        np.testing.assert_array_equal(runs[1].metrics[column], 0.5 * runs[0].metrics[column])
    np.testing.assert_array_equal(runs[1].state[["ee_x", "ee_y", "ee_z"]], 0.5 * runs[0].state[["ee_x", "ee_y", "ee_z"]])
    assert runs[1].outcome["outcome"] == runs[0].outcome["outcome"]
