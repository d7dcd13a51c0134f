"""analysis/make_tables.py and make_figures.py on a small folder of real recordings.

The folder: tiny dynamic-sphere episodes (16 rollouts, horizon 3; environments 0-4 end in a mix
of outcomes; one more at a goal position), four tiny cluttered episodes (one at a sparser cloud, one
with another goal), two tiny episodes behind the window (the release and paper controllers: the worlds
table and its solver ratio), and two tiny networks trained and timed by scenarios.reproduce (Table II: with
and without the over-estimation loss). The CSV numbers are checked against values computed here from what the
episodes returned (EpisodeResult) and from the saved weights evaluated again, not from the
recordings the scripts read.
"""

from __future__ import annotations

import dataclasses
import math
import os
import shutil
import subprocess
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd
import pytest

from analysis.load import NOT_RECORDED, machine_name
from ncedf.data import DatasetConfig, ValidationConfig, load_dataset
from ncedf.evaluate import INFERENCE_POINTS
from ncedf.model import load_model
from ncedf.robot import RobotSpec
from ncedf.train import evaluate_model
from scenarios import floor, manifest, reproduce
from scenarios.episode import EpisodeSettings, episode_name, run_episode
from scenarios.oracle import OracleResult
from scenarios.spheres import make_environment

ROOT = Path(__file__).resolve().parents[2]
Z = 1.959963984540054
SPHERE_ENVS = 5
#: A cluttered goal other than the paper's (a position: no random draw to compile), 0.45 m from the straight
#: robot's tip, outside the scene's 0.4 m tolerance: the one cluttered episode of the folder that reaches its goal.
OTHER_GOAL = "0.0,0.45,7.95"
#: A goal position among the spheres.
SPHERE_GOAL = "-4.0,0.0,4.0"
TINY_BUDGET = dataclasses.replace(
    reproduce.QUICK,
    networks=dataclasses.replace(reproduce.QUICK.networks, epochs=2, configs=4, grid=6, surface=20, val_configs=4,
                                 val_points=64, val_surface=8),
    timing=reproduce.TimingBudget(repeats=3, samples=16, horizon=3, shapes=("spheres",), links=(4, 5), points=(250,)))


def sphere_settings(env: int, goal: str = "fixed") -> EpisodeSettings:
    return EpisodeSettings("spheres", 4, seed=0, env_seed=env, shape="spheres", controller="paper", samples=16,
                           horizon=3, max_steps=25, goal=goal)


def cluttered_settings(seed: int, density: str | None = None, goal: str = "fixed") -> EpisodeSettings:
    options = (("density", density),) if density else ()
    return EpisodeSettings("cluttered", 4, seed=seed, shape="spheres", controller="paper", samples=16, horizon=3,
                           max_steps=4, options=options, goal=goal)


def window_settings(controller: str) -> EpisodeSettings:
    return EpisodeSettings("window", 4, seed=0, shape="spheres", controller=controller, samples=16, horizon=3,
                           max_steps=3)


@pytest.fixture(scope="module", autouse=True)
def cache(tmp_path_factory):
    """Datasets in a temporary cache folder (the scripts inherit it)."""
    previous = os.environ.get("NCEDF_CACHE")
    os.environ["NCEDF_CACHE"] = str(tmp_path_factory.mktemp("cache"))
    yield
    if previous is None:
        del os.environ["NCEDF_CACHE"]
    else:
        os.environ["NCEDF_CACHE"] = previous


@pytest.fixture(scope="module")
def folder(tmp_path_factory, cache):
    """Recordings and what their runs returned: (folder, {stem: EpisodeResult}, datasets)."""
    runs = tmp_path_factory.mktemp("runs")
    results = {}
    for settings in [sphere_settings(e) for e in range(SPHERE_ENVS)] + [sphere_settings(0, SPHERE_GOAL)] + [
            cluttered_settings(s) for s in (0, 1)] + [cluttered_settings(0, density="2"),
                                                      cluttered_settings(0, goal=OTHER_GOAL)] + [
            window_settings(c) for c in ("release", "paper")]:
        sub = runs / settings.scenario
        sub.mkdir(exist_ok=True)
        name = episode_name(settings)
        results[name] = (settings, run_episode(settings, sub / name, formats=("mcap",)))
    spec = RobotSpec(n_links=1)
    nets = TINY_BUDGET.networks
    data_cfg = DatasetConfig(n_configs=nets.configs, grid=nets.grid, n_surface=nets.surface)
    val_cfg = ValidationConfig(n_configs=nets.val_configs, n_points=nets.val_points, n_surface=nets.val_surface)
    data, val = load_dataset(data_cfg, spec), load_dataset(val_cfg, spec)
    where = reproduce.folder(runs, "table2", TINY_BUDGET)
    reproduce.write_manifest(where, "table2", TINY_BUDGET, "test", {})
    points = reproduce.timing_points(INFERENCE_POINTS)
    for net in reproduce.networks("table2", TINY_BUDGET):
        reproduce.train_network(net, where, TINY_BUDGET, data, val, points, seed=0)
    assert reproduce.run_timing(runs, TINY_BUDGET, 0, "test") == 0
    return runs, results, val


def script(name: str, *args) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, f"analysis/{name}", *map(str, args)], cwd=ROOT, capture_output=True,
                          text=True, timeout=300)


@pytest.fixture(scope="module")
def verdicts(folder):
    """Floor verdicts planted for the sphere environments no episode solved: a found motion where the
    episode collided, else in turn certain and none found: {(goal, env): "found" | "certain" | "none"}."""
    runs, results, _ = folder
    open_envs, others = floor.open_environments(runs)
    outcome = {(s.goal, s.env_seed): r.outcome for s, r in results.values() if s.scenario == "spheres"}
    assert open_envs == sorted((4, *k) for k, o in outcome.items() if o != "success")
    assert open_envs and others == 0
    assert "collision" in outcome.values(), "the fixture should give a collision to judge"
    spec, planted = RobotSpec(4), {}
    for i, (_, goal, env) in enumerate(open_envs):
        world, target, _ = make_environment(env, spec, goal)
        arcs = np.repeat(np.asarray(spec.straight_state(), np.float64)[None], 3, axis=0)
        kind = "found" if outcome[(goal, env)] == "collision" else ("certain", "none")[i % 2]
        verdict = {"found": floor.Verdict(None, False, OracleResult(2, 8, arcs, 0.4)),
                   "certain": floor.Verdict(3, True, None),
                   "none": floor.Verdict(None, False, OracleResult(None, None, None, math.nan))}[kind]
        floor.record_verdict(floor.verdict_stem(runs / floor.SCENARIO, goal, env), goal, env, world, target, spec,
                             verdict)
        planted[(goal, env)] = kind
    return planted


@pytest.fixture(scope="module")
def tables(folder, verdicts, tmp_path_factory):
    runs, _, _ = folder
    out = tmp_path_factory.mktemp("tables")
    done = script("make_tables.py", runs, "--out", out)
    assert done.returncode == 0, done.stderr
    return out, done


def wilson_by_roots(k: int, n: int) -> tuple[float, float]:
    """The Wilson interval as the roots in p of (k/n - p)^2 = Z^2 p (1 - p) / n."""
    a = 1 + Z * Z / n
    b = -(2 * k / n + Z * Z / n)
    c = (k / n) ** 2
    return tuple(sorted(np.roots([a, b, c]).real))


def pooled(results) -> tuple[float, float]:
    """Mean and std of the solver time over every MPPI step of these episodes, from their per-episode stats."""
    n = np.array([r.steps for r in results], float)
    m = np.array([r.solver_ms_mean for r in results])
    s = np.array([r.solver_ms_std for r in results])
    mean = (n * m).sum() / n.sum()
    second = (n * (s**2 + m**2)).sum() / n.sum()
    return mean / 1e3, math.sqrt(second - mean**2) / 1e3


def test_table3_rates_and_times_match_the_episodes(folder, tables, verdicts):
    _, results, _ = folder
    out, _ = tables
    df = pd.read_csv(out / "table3.csv")
    assert sorted(df["goal"]) == sorted(["fixed", SPHERE_GOAL])  # other goals get rows of their own
    row = df.set_index("goal").loc["fixed"]
    ours = [r for s, r in results.values() if s.scenario == "spheres" and s.goal == "fixed"]
    outcomes = [r.outcome for r in ours]
    assert len(set(outcomes)) > 1, "the fixture should give a mix of outcomes"
    assert row["episodes"] == SPHERE_ENVS and row["shape"] == "spheres"
    for name in ("success", "collision", "stuck"):
        k = outcomes.count(name)
        assert row[f"n_{name}"] == k
        assert row[name] == pytest.approx(k / SPHERE_ENVS, abs=1e-6)
        low, high = wilson_by_roots(k, SPHERE_ENVS)
        assert row[f"{name}_low"] == pytest.approx(low, abs=1e-5)
        assert row[f"{name}_high"] == pytest.approx(high, abs=1e-5)
    mean, std = pooled(ours)
    assert row["mppi_step_s_mean"] == pytest.approx(mean, rel=1e-4)
    assert row["mppi_step_s_std"] == pytest.approx(std, rel=1e-3)
    assert row["mppi_steps"] == sum(r.steps for r in ours)
    assert row["paper_success"] == 0.872 and row["controller"] == "paper" and row["samples"] == 16
    planted = {env: kind for (goal, env), kind in verdicts.items() if goal == "fixed"}
    collided = [s.env_seed for s, r in results.values() if s.scenario == "spheres" and s.goal == "fixed"
                and r.outcome == "collision"]
    assert row["n_certain"] == sum(k == "certain" for k in planted.values())
    assert row["n_unsolved"] == sum(k in ("certain", "none") for k in planted.values())
    assert row["n_avoidable"] == sum(planted.get(env) == "found" for env in collided) == len(collided)
    low, high = wilson_by_roots(int(row["n_unsolved"]), SPHERE_ENVS)
    assert row["unsolved_low"] == pytest.approx(low, abs=1e-5) and row["unsolved_high"] == pytest.approx(high, abs=1e-5)
    other = df.set_index("goal").loc[SPHERE_GOAL]
    at_goal = [r for s, r in results.values() if s.scenario == "spheres" and s.goal == SPHERE_GOAL]
    assert other["episodes"] == 1 and other[f"n_{at_goal[0].outcome}"] == 1
    assert math.isnan(other["paper_success"])  # the paper's figures are for its own goals


def test_avoidable_is_unknown_while_a_collision_is_neither_judged_nor_solved(folder, tmp_path):
    """The sphere recordings without the floor's verdicts: each collision is in an environment that no
    recorded episode solved (one episode each), so a row with one has no avoidable rate, not 0."""
    runs, results, _ = folder
    shutil.copytree(runs / "spheres", tmp_path / "runs" / "spheres")
    done = script("make_tables.py", tmp_path / "runs", "--out", tmp_path / "tables")
    assert done.returncode == 0, done.stderr
    df = pd.read_csv(tmp_path / "tables" / "table3.csv").set_index("goal")
    collided = {goal: sum(s.goal == goal and r.outcome == "collision" for s, r in results.values()
                          if s.scenario == "spheres") for goal in df.index}
    assert any(collided.values()), "the fixture should give a collision"
    for goal, row in df.iterrows():
        if collided[goal]:
            assert math.isnan(row["avoidable"]) and math.isnan(row["n_avoidable"])
        else:
            assert row["avoidable"] == row["n_avoidable"] == 0
    assert f"{sum(collided.values())} collisions lie in environments with no verdict" in done.stdout


def test_table4_matches_the_episodes(folder, tables):
    _, results, _ = folder
    out, _ = tables
    df = pd.read_csv(out / "table4.csv")
    # a denser or sparser cloud, and other goals, get rows of their own
    assert sorted(zip(df["goal"], df["density"])) == sorted([("fixed", 2.0), ("fixed", 4.0), (OTHER_GOAL, 4.0)])
    row = df.set_index(["goal", "density"]).loc[("fixed", 4.0)]
    ours = [r for s, r in results.values() if s.scenario == "cluttered" and not s.options and s.goal == "fixed"]
    assert row["links"] == 4 and row["episodes"] == len(ours) == 2
    assert row["n_success"] == sum(r.outcome == "success" for r in ours)
    mean, std = pooled(ours)
    assert row["mppi_step_s_mean"] == pytest.approx(mean, rel=1e-4)
    assert row["paper_reach_step"] == 158
    other = df.set_index(["goal", "density"]).loc[(OTHER_GOAL, 4.0)]
    drawn = [r for s, r in results.values() if s.scenario == "cluttered" and s.goal == OTHER_GOAL]
    assert other["episodes"] == len(drawn) == 1 and drawn[0].outcome == "success" and other["n_success"] == 1
    assert other["success"] == 1.0 and other["reached"] == 1 and other["reach_step_mean"] == drawn[0].reach_step > 0
    assert row["n_success"] == 0 and row["reached"] == 0 and math.isnan(row["reach_step_mean"])
    assert math.isnan(other["paper_reach_step"])  # the paper has figures for its own goal only


def test_the_worlds_table_matches_the_episodes(folder, tables):
    _, results, _ = folder
    out, _ = tables
    df = pd.read_csv(out / "worlds.csv").set_index("controller")
    runs = {s.controller: r for s, r in results.values() if s.scenario == "window"}
    assert sorted(df.index) == ["paper", "release"] and set(df["world"]) == {"window"}
    for controller, result in runs.items():
        row = df.loc[controller]
        assert row["episodes"] == 1 and row["n_success"] == (result.outcome == "success")
        assert row["min_clearance"] == pytest.approx(result.min_true_distance, rel=1e-5, abs=1e-6)  # 6 digits in the CSV
        assert row["solver_ms"] == pytest.approx(pooled([result])[0] * 1e3, rel=1e-4)
    assert df.loc["release", "solver_vs_paper"] == pytest.approx(
        df.loc["release", "solver_ms"] / df.loc["paper", "solver_ms"], rel=1e-4)
    assert df.loc["paper", "solver_vs_paper"] == pytest.approx(1.0)


def test_table2_metrics_match_the_saved_networks(folder, tables):
    runs, _, val = folder
    out, done = tables
    df = pd.read_csv(out / "table2.csv")
    assert sorted(df["lambda_over"]) == [0.0, 2.0]
    for row in df.itertuples():
        net = reproduce.Network(4, 16, row.encoding, row.lambda_over)
        model = load_model(reproduce.folder(runs, "table2", TINY_BUDGET) / net.name)
        again = evaluate_model(model, val)
        for key in ("mae", "rmse", "moe", "over_p999"):
            assert getattr(row, key) == pytest.approx(again[key], rel=1e-4, abs=1e-6)
        assert row.epochs == TINY_BUDGET.networks.epochs and row.timing_repeats == TINY_BUDGET.timing.repeats
        assert row.inference_ms_mean > 0 and row.mppi_step_ms_mean > 0 and row.quick
    assert "(quick)" in (out / "table2.md").read_text() and "0.017 / 0.024 / 0.002" in done.stdout
    here = manifest.machine()  # every network of the fixture was trained and timed by this process
    assert set(df["machine"]) == {f"{here['cpu']}, {here['cores']} cores, {here['device']}"}
    assert f"1 = {df['machine'][0]}" in done.stdout and NOT_RECORDED not in done.stdout


def test_a_run_that_names_no_machine_reads_not_recorded():
    """Networks recorded before runs named their machine: no machine metadata, or a NaN where other
    runs of the same table name one."""
    named = pd.Series({"machine.cpu": "X", "machine.cores": 2.0, "machine.device": "cpu"})
    assert machine_name(named) == "X, 2 cores, cpu"
    assert machine_name(pd.Series({"mae.last": 0.1})) == NOT_RECORDED
    assert machine_name(pd.Series({"machine.cpu": np.nan, "machine.cores": np.nan})) == NOT_RECORDED


def test_a_network_stopped_midway_goes_on_from_its_last_epoch(folder, tmp_path, monkeypatch):
    """The first network of Table II stopped after its first epoch (its state saved, its recording
    interrupted), then trained again: its recording holds every epoch once and its weights are those of
    the fixture's run, never stopped; no training state is left beside either."""
    import ncedf.train_state
    from recorder import load_run

    runs, _, _ = folder
    done = reproduce.folder(runs, "table2", TINY_BUDGET)
    assert not list(done.glob(f"*{reproduce.STATE_SUFFIX}"))
    net = reproduce.networks("table2", TINY_BUDGET)[0]
    spec = RobotSpec(n_links=1)
    nets = TINY_BUDGET.networks
    data = load_dataset(DatasetConfig(n_configs=nets.configs, grid=nets.grid, n_surface=nets.surface), spec)
    val = load_dataset(ValidationConfig(n_configs=nets.val_configs, n_points=nets.val_points,
                                        n_surface=nets.val_surface), spec)
    points = reproduce.timing_points(INFERENCE_POINTS)
    save = ncedf.train_state.save_state

    def save_then_stop(path, state, fingerprint):
        save(path, state, fingerprint)
        raise KeyboardInterrupt  # as Ctrl-C after the first epoch

    monkeypatch.setattr(ncedf.train_state, "save_state", save_then_stop)
    with pytest.raises(KeyboardInterrupt):
        reproduce.train_network(net, tmp_path, TINY_BUDGET, data, val, points, seed=0)
    assert load_run(tmp_path / f"{net.name}.mcap").outcome["outcome"] == "interrupted"
    monkeypatch.setattr(ncedf.train_state, "save_state", save)
    reproduce.train_network(net, tmp_path, TINY_BUDGET, data, val, points, seed=0)
    run = load_run(tmp_path / f"{net.name}.mcap")
    assert run.outcome["outcome"] == "success" and list(run.metrics["step"][:nets.epochs]) == [1, 2]
    again, before = load_model(tmp_path / net.name), load_model(done / net.name)
    assert all(np.array_equal(a, b) for a, b in zip(jax.tree_util.tree_leaves(again.params),
                                                    jax.tree_util.tree_leaves(before.params), strict=True))
    assert not list(tmp_path.glob(f"*{reproduce.STATE_SUFFIX}"))


def test_missing_tables_name_their_command(tables):
    out, done = tables
    assert "python -m scenarios.reproduce table1" in done.stderr
    assert not (out / "table1.csv").exists()
    for name in ("table2", "table3", "table4"):
        assert (out / f"{name}.tex").read_text().startswith("\\begin{table}")


def test_corrupt_and_unclosed_recordings_are_listed_and_left_out(folder, tmp_path):
    runs, _, _ = folder
    copy = tmp_path / "runs"
    shutil.copytree(runs, copy)
    assert script("make_tables.py", copy, "--out", tmp_path / "t").returncode == 0  # reads cleanly first
    (copy / "spheres" / "garbage.mcap").write_bytes(b"not a recording at all")
    first = sorted((copy / "spheres").glob("spheres_*.mcap"))[0]
    data = first.read_bytes()
    first.write_bytes(data[: len(data) * 2 // 3])  # killed writer: no footer
    done = script("make_tables.py", copy, "--out", tmp_path / "t")
    assert done.returncode == 0, done.stderr
    assert "garbage.mcap" in done.stderr and first.name in done.stderr and "left out 2" in done.stderr
    assert pd.read_csv(tmp_path / "t" / "table3.csv")["episodes"].sum() == SPHERE_ENVS  # of SPHERE_ENVS + 1


def test_figures_and_their_data(folder, tmp_path):
    runs, results, _ = folder
    done = script("make_figures.py", runs, "--out", tmp_path)
    assert done.returncode == 0, done.stderr
    for name in ("fig3_ncedf_slices", "fig4_sphere_distances", "fig5_cluttered_L4", "mppi_time_vs_links",
                 "mppi_time_vs_points", "success_rates"):
        assert (tmp_path / f"{name}.png").stat().st_size > 10_000, name
        assert (tmp_path / f"{name}.csv").is_file(), name
    assert "no 5-link cluttered recordings" in done.stderr
    links = pd.read_csv(tmp_path / "mppi_time_vs_links.csv")
    assert list(links["links"]) == [4, 5] and (links["timed_steps"] == TINY_BUDGET.timing.repeats).all()
    points = pd.read_csv(tmp_path / "mppi_time_vs_points.csv")
    assert sorted(points["observed_points"]) == [250, 500] and (points["mppi_step_s_mean"] > 0).all()
    fig4 = pd.read_csv(tmp_path / "fig4_sphere_distances.csv")
    stem = Path(fig4["run"].iloc[0]).stem
    settings, result = results[stem]
    assert settings.goal == "fixed"  # the paper's goal first
    assert fig4["true_min_distance"].min() == pytest.approx(result.min_true_distance, abs=1e-6)
    assert len(fig4) == result.steps + 1 or result.outcome == "collision"
    rates = pd.read_csv(tmp_path / "success_rates.csv").set_index("goal")
    for goal in ("fixed", SPHERE_GOAL):
        spheres = [r for s, r in results.values() if s.scenario == "spheres" and s.goal == goal]
        assert rates.loc[goal, "successes"] == sum(r.outcome == "success" for r in spheres)
    assert rates.loc["fixed", "paper_success"] == 0.872 and math.isnan(rates.loc[SPHERE_GOAL, "paper_success"])
    fig3 = pd.read_csv(tmp_path / "fig3_ncedf_slices.csv")
    model = load_model()
    for (theta, phi), rows in fig3.groupby(["theta", "phi"]):
        uz = rows[["u", "z"]].to_numpy()
        truth = _annular_sector_distance(uz, theta, model.spec.length, model.spec.radius)
        assert np.abs(rows["exact"] - truth).max() < 1e-3
        points = uz[:, :1] * np.array([math.cos(phi), math.sin(phi), 0.0]) + uz[:, 1:] * np.array([0.0, 0.0, 1.0])
        learned = np.asarray(jax.jit(model.link_distance)(jnp.asarray(points, jnp.float32), theta, phi))
        assert np.allclose(rows["learned"], learned, atol=1e-5)
        assert np.abs(rows["difference"] - (learned - truth)).max() < 1e-3
        assert np.abs(learned - truth).mean() < 0.02  # the shipped model's error, the figure's subject


def _annular_sector_distance(uz: np.ndarray, theta: float, length: float, r: float) -> np.ndarray:
    """Distance (m) from points (u, z) of a link's bending plane to the boundary of the link's slice there,
    by dense brute force: the slice is the annular sector of radii R -+ r round (R, 0), R = L / theta,
    from the base (angle pi) through theta; its boundary the two arcs and the two end segments."""
    from scipy.spatial import cKDTree

    big = length / theta
    angles = np.pi - np.linspace(0.0, theta, 40_001)
    arcs = [np.stack([big + rho * np.cos(angles), rho * np.sin(angles)], -1) for rho in (big - r, big + r)]
    across = np.linspace(-r, r, 4001)[:, None]
    ends = [np.array([big, 0.0]) + (big + across) * np.array([math.cos(a), math.sin(a)])
            for a in (np.pi, np.pi - theta)]
    return cKDTree(np.concatenate(arcs + ends)).query(uz)[0]


def test_the_cluttered_snapshots_draw_the_papers_goal_only(folder):
    from analysis.figures import snapshot_strip
    from analysis.load import load

    rec = load(folder[0])
    drawn = rec.runs[(rec.runs["scenario"] == "cluttered") & (rec.runs["goal_kind"] == OTHER_GOAL)]
    assert len(drawn) == 1
    fig, data = snapshot_strip(dataclasses.replace(rec, runs=rec.runs.drop(drawn.index)), 4)
    assert set(data["run"]) != set(drawn["path"])
    message = snapshot_strip(dataclasses.replace(rec, runs=drawn), 4)
    assert isinstance(message, str) and "skipped" in message


def test_reproduce_skips_complete_networks_and_timing_cases(folder, capsys):
    runs, _, _ = folder
    where = reproduce.folder(runs, "table2", TINY_BUDGET)
    before = {p: p.stat().st_mtime_ns for p in where.glob("net_*.mcap")}
    assert len(before) == 2
    assert reproduce.run_networks("table2", runs, TINY_BUDGET, 0, "test") == 0
    assert reproduce.run_timing(runs, TINY_BUDGET, 0, "test") == 0
    err = capsys.readouterr().err
    assert "2 networks in" in err and "0 to train" in err and "0 to run" in err
    assert {p: p.stat().st_mtime_ns for p in where.glob("net_*.mcap")} == before


def test_a_runs_folder_where_there_is_one_is_the_default(tmp_path):
    """make_tables with no argument reads runs/ where there is one (else the current folder: the
    user's day, ``tests/integration/test_users_day.py``); a folder without recordings is refused in
    one line, and no tables folder is made."""
    shutil.copy(ROOT / "results" / "closed_loop" / "cluttered_L7_ours_s0.mcap", tmp_path / "recording.mcap")
    (tmp_path / "runs").mkdir()
    done = subprocess.run([sys.executable, str(ROOT / "analysis" / "make_tables.py")], cwd=tmp_path,
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 2 and done.stderr.startswith("error: no recordings (.mcap, .rrd) under runs;")
    assert len(done.stderr.strip().splitlines()) == 1 and not (tmp_path / "tables").exists()
    shutil.move(tmp_path / "recording.mcap", tmp_path / "runs")
    done = subprocess.run([sys.executable, str(ROOT / "analysis" / "make_tables.py")], cwd=tmp_path,
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0 and "read 1 recordings under runs" in done.stderr


@pytest.mark.parametrize("command", ["make_tables", "make_figures"])
def test_an_output_folder_that_cannot_hold_files_is_a_one_line_error(tmp_path, capsys, command):
    import importlib

    main = importlib.import_module(f"analysis.{command}").main
    runs = tmp_path / "runs"
    shutil.copy(ROOT / "results" / "closed_loop" / "cluttered_L7_ours_s0.mcap", runs.mkdir() or runs / "r.mcap")
    (tmp_path / "taken").write_text("a file of the user's")
    for out, why in [(tmp_path / "taken", "taken"), ("/proc/tables", "/proc/tables")]:  # /proc: not even as root
        assert main([str(runs), "--out", str(out)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert err == [err[0]] and err[0].startswith(f"error: cannot write {command[5:]} to") and why in err[0]
    assert (tmp_path / "taken").read_text() == "a file of the user's"


def test_a_run_of_another_robot_or_scale_is_labelled_by_what_differs():
    from analysis.load import robot_label

    assert robot_label(pd.Series({"robot.length": 2.0, "robot.radius": 0.2})) == ""
    small = pd.Series({"robot.length": 0.1, "robot.radius": 0.01, "settings.options": [["scale", "0.05"]]})
    assert robot_label(small) == "L 0.1 m, r 0.01 m, scale 0.05"
    assert robot_label(pd.Series({"robot.length": 2.0, "robot.radius": [0.25, 0.2, 0.15]})) == "r 0.25-0.15 m"


def test_table3_keeps_other_robots_in_rows_of_their_own_with_their_own_floor(tmp_path):
    """Sphere episodes of 4 and 5 links and of a scaled 4-link robot in one folder: a row each; only the
    paper's robot's row has the paper's figures; a 5-link verdict does not judge the 4-link robot's
    environment, nor a 4-link success the 5-link one's; the floor's note counts the unjudged collisions
    of the paper's links (4 and 5), not the scaled robot's, which the floor never judges."""
    from analysis.load import load
    from analysis.tables import table3
    from recorder import Recorder

    def record(name, meta, outcome):
        with Recorder(tmp_path / name, meta, formats=("mcap",)) as rec:
            rec.log_step(0, 0.0, metrics={"solver_ms": 2.0})
            rec.finish({"outcome": outcome, "steps": 1})

    for links, env, outcome, length in ((4, 0, "collision", 2.0), (4, 2, "success", 2.0), (5, 0, "success", 2.0),
                                        (5, 2, "collision", 2.0), (4, 2, "collision", 1.0)):
        record(f"L{links}_env{env}_{length}", {
            "scenario": "spheres", "links": links, "env_seed": env, "settings": {"goal": "fixed"}, "shape": "ncedf",
            "controller": "ours", "mppi": {"samples": 16, "horizon": 3}, "max_steps": 25,
            "robot": {"length": length}}, outcome)
    record("floor_fixed_env0_L5", {"scenario": "floor", "links": 5, "env_seed": 0, "settings": {"goal": "fixed"}},
           "success")
    table = table3(load(tmp_path))
    data = table.data.set_index(["links", "robot"])
    assert list(data.index) == [(4, ""), (4, "L 1 m"), (5, "")] and list(data["episodes"]) == [2, 1, 2]
    assert data.loc[(4, ""), "paper_success"] == pytest.approx(0.986)
    assert np.isnan(data.loc[(5, ""), "paper_success"]) and np.isnan(data.loc[(4, "L 1 m"), "paper_success"])
    assert np.isnan(data.loc[(4, ""), "avoidable"]) and np.isnan(data.loc[(5, ""), "avoidable"])
    assert any(note.startswith("2 collisions lie in environments with no verdict") for note in table.notes)
