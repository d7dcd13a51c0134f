"""Sweeps: recordings per episode, resumption, failure isolation, Ray, CLI errors and interruption.

Tiny episodes (16 rollouts, horizon 3, at most 25 steps: environments 0-4 end in a mix of
outcomes) of the spheres scenario with the spheres representation and the release controller (the
sweep's machinery is the subject: its programs load in a worker in half the time of ``ours``); the
sweeps share one persistent compilation cache, so the configuration compiles once for the whole file.
"""

import contextlib
import io
import os
import re
import shutil
import signal
import subprocess
import sys
import time
import warnings
from collections import Counter
from pathlib import Path
from types import SimpleNamespace

import pandas as pd
import pytest
import ray

from recorder import Recorder, load_run, load_runs
import scenarios.episode
import scenarios.sweep
from scenarios import manifest
from scenarios.episode import EpisodeSettings, episode_name
from scenarios.sweep import (FINAL_OUTCOMES, JAX_CACHE, Recorded, _local_episode, main, read_complete, release_programs,
                             run_one, run_sweep, sweep_settings)

TINY = ["--scenario", "spheres", "--shapes", "spheres", "--controllers", "release", "--samples", "16",
        "--horizon", "3"]
STEPS = 25
ENVS = 5
#: Metrics that are a function of the settings (solver_ms is wall time).
DETERMINISTIC = ["step", "sim_time", "goal_distance", "predicted_min_distance", "true_min_distance"]


def tiny(env_seed: int, max_steps: int = STEPS) -> EpisodeSettings:
    return EpisodeSettings(scenario="spheres", links=4, seed=0, env_seed=env_seed, shape="spheres",
                           controller="release", samples=16, horizon=3, max_steps=max_steps)


def cli(argv) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        status = main(argv)
    return status, out.getvalue(), err.getvalue()


def table_counts(text: str) -> dict[str, int]:
    """Outcome counts of the single row of a summary table."""
    lines = [line for line in text.splitlines() if line.strip()]
    header = re.split(r"\s{2,}", lines[0])
    row = dict(zip(header, re.split(r"\s{2,}", lines[1])))
    counts = {o: int(re.search(r"\((\d+)\)", row[o]).group(1)) for o in FINAL_OUTCOMES}
    counts["episodes"] = int(row["episodes"])
    return counts


def deterministic(path: Path) -> pd.DataFrame:
    return load_run(path).metrics[DETERMINISTIC]


@pytest.fixture(scope="module")
def swept(tmp_path_factory):
    """The tiny sweep run once from the CLI, with one worker: (folder, exit status, stdout, stderr)."""
    out = tmp_path_factory.mktemp("sweep") / "runs"
    status, stdout, stderr = cli([*TINY, "--max-steps", str(STEPS), "--envs", str(ENVS), "--workers", "1",
                                  "--out", str(out)])
    return out, status, stdout, stderr


@pytest.fixture()
def copy_of(swept, tmp_path):
    """A copy of the swept folder (its compilation cache included) for tests that change it."""
    out = tmp_path / "runs"
    shutil.copytree(swept[0], out)
    return out


def episode_files(out: Path) -> list[Path]:
    """The episodes' recordings in a sweep folder (not its manifest), sorted."""
    return sorted(p for p in out.glob("*.mcap") if p.stem != manifest.STEM)


def test_a_sweep_records_every_episode_and_counts_their_outcomes(swept):
    out, status, stdout, stderr = swept
    assert status == 0, stderr
    expected = {episode_name(tiny(e)) for e in range(ENVS)}
    assert {p.stem for p in out.glob("*.mcap")} == expected | {manifest.STEM} and not list(out.glob("*.rrd"))
    runs, _ = load_runs(out)  # the episodes: the manifest is listed apart
    assert list(load_runs(out, kind="manifests")[0]["path"]) == [str(out / f"{manifest.STEM}.mcap")]
    assert runs["complete"].all() and set(runs["outcome"]) <= set(FINAL_OUTCOMES)
    assert len(set(runs["outcome"])) > 1, "the tiny episodes should end in a mix of outcomes"
    for path in runs["path"]:  # each recording holds the settings it is named after
        assert episode_name(EpisodeSettings.from_dict(load_run(path).meta["settings"])) == Path(path).stem
    read_back = Counter(runs["outcome"])
    assert table_counts(stdout) == {**{o: read_back[o] for o in FINAL_OUTCOMES}, "episodes": ENVS}


def test_a_rerun_skips_every_complete_episode(swept):
    out, _, first_stdout, _ = swept
    before = {p: p.stat().st_mtime_ns for p in episode_files(out)}
    status, stdout, stderr = cli([*TINY, "--max-steps", str(STEPS), "--envs", str(ENVS), "--workers", "1",
                                  "--out", str(out)])
    assert status == 0, stderr
    assert f"{ENVS} complete, 0 to run" in stderr
    assert {p: p.stat().st_mtime_ns for p in episode_files(out)} == before
    assert table_counts(stdout) == table_counts(first_stdout)


def test_the_grid_holds_every_combination_once_grouped_by_configuration():
    grid = sweep_settings(["spheres", "cluttered"], [4, 5], ["ncedf", "pointcloud:10"], ["paper", "release"],
                          envs=2, seeds=3, samples=16)
    cells = {(s.scenario, s.links, s.shape, s.controller, s.env_seed, s.seed) for s in grid}
    assert len(grid) == len(cells) == 2 * 2 * 2 * 2 * 2 * 3
    assert len({episode_name(s) for s in grid}) == len(grid) and all(s.samples == 16 for s in grid)
    configurations = [(s.scenario, s.links, s.shape, s.controller) for s in grid]
    blocks = [c for i, c in enumerate(configurations) if i == 0 or configurations[i - 1] != c]
    assert len(blocks) == len(set(configurations)) == 16  # each configuration's episodes run in a row


@pytest.mark.parametrize("outcome, formats, complete", [
    ("stuck", ("mcap",), True), ("interrupted", ("mcap",), False), (None, ("mcap",), False),
    ("success", ("mcap", "rrd"), False),  # the .rrd is missing
])
def test_only_closed_recordings_with_a_final_outcome_count_as_complete(tmp_path, outcome, formats, complete):
    stem = tmp_path / "episode"
    rec = Recorder(stem, {"scenario": "synthetic"}, formats=("mcap",))
    rec.log_step(0, 0.0, metrics={"solver_ms": 2.0})
    rec.log_step(1, 0.05, metrics={"solver_ms": 4.0})
    if outcome is None:  # a killed run: flushed, never closed
        rec.flush()
        assert read_complete(stem, formats) is None
        return
    rec.finish({"outcome": outcome, "steps": 2})
    assert read_complete(stem, formats) == (Recorded(outcome, 3.0) if complete else None)


def test_a_corrupt_recording_is_run_again_and_a_failing_episode_stops_no_other(copy_of, capsys):
    victim, *kept = episode_files(copy_of)
    original, kept_mtimes = deterministic(victim), [p.stat().st_mtime_ns for p in kept]
    victim.write_bytes(victim.read_bytes()[: victim.stat().st_size // 2])
    missing = copy_of / "missing.stl"
    bad = EpisodeSettings(scenario="custom", links=4, seed=0, shape="spheres", samples=16, horizon=3, max_steps=3,
                          options=(("obstacles", str(missing)), ("goal_position", "4,0,4")))
    episodes = [bad, *(tiny(e) for e in range(ENVS))]
    with pytest.raises(ValueError, match="missing.stl"):  # checked before anything is written ...
        run_sweep(episodes, copy_of / "checked", workers=1)
    assert not (copy_of / "checked").exists()

    report = run_sweep(episodes, copy_of, workers=1, check=False)  # ... or reported when it runs
    states = {e.settings: e.state for e in report.episodes}
    assert states == {bad: "failed", **{tiny(e): "run" if episode_name(tiny(e)) == victim.stem else "skipped"
                                        for e in range(ENVS)}}
    assert report.exit_status == 1 and "missing.stl" in report.episodes[0].error
    lines = [line for line in capsys.readouterr().err.splitlines() if line.startswith("failed:")]
    assert len(lines) == 1 and episode_name(bad) in lines[0] and "missing.stl" in lines[0]
    assert load_run(victim).complete and [p.stat().st_mtime_ns for p in kept] == kept_mtimes
    pd.testing.assert_frame_equal(deterministic(victim), original)  # same settings, same episode


# Ray starts its processes by fork + exec, which JAX's at-fork hook warns about needlessly.
@pytest.mark.filterwarnings("ignore:os.fork:RuntimeWarning")
def test_ray_runs_the_same_episodes(swept, tmp_path):
    out = tmp_path / "ray"
    ray.init(num_cpus=1, include_dashboard=False)
    try:
        report = run_sweep([tiny(e) for e in range(ENVS)], out, executor="ray", progress=False,
                           jax_cache=swept[0] / JAX_CACHE)
    finally:
        ray.shutdown()
    assert report.count("run") == ENVS and report.exit_status == 0 and len(list(out.glob("*.mcap"))) == ENVS
    for path in out.glob("*.mcap"):  # same settings, same episodes
        pd.testing.assert_frame_equal(deterministic(path), deterministic(swept[0] / path.name))


@pytest.mark.parametrize("args, named", [
    (["--envs", "0"], "--envs: .*0"),
    (["--links", "4,x"], "'4,x'"),
    (["--shapes", "spheres,bogus"], "'bogus'"),
    (["--controllers", "fast"], "'fast'"),
    (["--formats", "mp4"], "'mp4'"),
    (["--workers", "0"], "--workers: .*0"),
    (["--option", "nokey"], "'nokey'"),
    (["--executor", "ray", "--workers", "2"], "--workers"),
    (["--links", "4,5,4"], "L4_spheres.* more than once"),
    (["--seed", "3"], "--seed 3"),  # a runner's option, not an abbreviation of --seeds
])
def test_bad_values_are_one_line_errors_and_write_nothing(tmp_path, capsys, args, named):
    out = tmp_path / "runs"
    try:
        status = main([*TINY, *args, "--out", str(out)])
    except SystemExit as exc:  # argparse's own errors
        status = exc.code
    err = capsys.readouterr().err.strip().splitlines()
    assert status == 2 and len(err) == 1 and re.search(named, err[0]), err
    assert not out.exists()


def test_an_out_folder_where_no_file_can_go_is_a_one_line_error(capsys):
    assert main([*TINY, "--out", "/proc/ncedf-runs"]) == 2  # os.access says yes to root; /proc takes no new file
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "cannot write recordings to /proc/ncedf-runs: /proc takes no files" in err[0]


def test_without_ray_the_ray_executor_is_a_one_line_error(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # as if not installed: `import ray` raises ImportError
    out = tmp_path / "runs"
    assert main([*TINY, "--executor", "ray", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "pip install 'ncedf[cluster]'" in err[0] and not out.exists()


def test_ctrl_c_keeps_complete_episodes_and_the_same_command_finishes_the_sweep(swept, tmp_path):
    out = tmp_path / "runs"
    shutil.copytree(swept[0] / JAX_CACHE, out / JAX_CACHE)
    envs = 12
    argv = [*TINY, "--max-steps", "3", "--envs", str(envs), "--workers", "1", "--out", str(out)]
    settings = [tiny(e, max_steps=3) for e in range(envs)]
    stems = [out / episode_name(s) for s in settings]
    proc = subprocess.Popen([sys.executable, "-m", "scenarios.sweep", *argv], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)
    deadline = time.monotonic() + 120
    while read_complete(stems[0], ("mcap",)) is None and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.05)
    os.killpg(proc.pid, signal.SIGINT)  # as Ctrl-C: the sweep and its workers
    _, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 130, stderr
    assert "Traceback" not in stderr
    last = stderr.strip().splitlines()[-1]
    found = re.fullmatch(rf"interrupted by SIGINT: (\d+) of {envs} episodes complete in .*", last)
    assert found, stderr
    kept = int(found.group(1))
    assert kept == sum(read_complete(stem, ("mcap",)) is not None for stem in stems)
    assert 1 <= kept < envs
    report = run_sweep(settings, out, workers=1, progress=False)
    assert report.count("skipped") == kept and report.count("run") == envs - kept and report.exit_status == 0


def children(pid: int) -> set[int]:
    """The child processes of ``pid``, over its threads."""
    found = set()
    for task in Path(f"/proc/{pid}/task").iterdir():
        with contextlib.suppress(FileNotFoundError, ProcessLookupError):  # a thread that ended meanwhile
            found.update(int(c) for c in (task / "children").read_text().split())
    return found


def spawned(pid: int) -> set[int]:
    """The worker processes among the children of ``pid``."""
    found = set()
    for c in children(pid):
        with contextlib.suppress(FileNotFoundError):  # one that exited meanwhile
            if b"spawn_main" in Path(f"/proc/{c}/cmdline").read_bytes():
                found.add(c)
    return found


def recording_open(pid: int) -> bool:
    """Whether process ``pid`` holds a recording open."""
    with contextlib.suppress(FileNotFoundError):
        return any(os.readlink(fd).endswith(".mcap") for fd in Path(f"/proc/{pid}/fd").iterdir())
    return False


def alive(pid: int) -> bool:
    try:
        return Path(f"/proc/{pid}/stat").read_text().split(")")[-1].split()[0] != "Z"
    except FileNotFoundError:
        return False


def test_sigterm_stops_the_workers_too(tmp_path):
    out = tmp_path / "runs"
    argv = [*TINY, "--envs", "2", "--workers", "1", "--out", str(out)]  # stopped while compiling
    proc = subprocess.Popen([sys.executable, "-m", "scenarios.sweep", *argv], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while not (out / JAX_CACHE).exists() and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.05)  # the worker compiles its first program
    started = children(proc.pid)
    proc.send_signal(signal.SIGTERM)  # to the sweep alone: it stops its worker
    _, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 143, stderr
    assert "Traceback" not in stderr
    assert re.fullmatch(r"interrupted by SIGTERM: 0 of 2 episodes complete in .*", stderr.strip().splitlines()[-1])
    deadline = time.monotonic() + 10  # the resource tracker leaves when it sees the sweep gone
    while any(alive(pid) for pid in started) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert started and not [pid for pid in started if alive(pid)]


def test_a_sweep_killed_midway_finishes_every_episode_once_when_run_again(swept, tmp_path):
    """SIGKILL to the sweep and its worker (nothing closed) once an episode is complete; the same
    command then finishes the sweep: every episode once and complete, the finished ones kept."""
    out = tmp_path / "runs"
    shutil.copytree(swept[0] / JAX_CACHE, out / JAX_CACHE)
    command = [sys.executable, "-m", "scenarios.sweep", *TINY, "--max-steps", str(STEPS), "--envs", "3",
               "--workers", "1", "--out", str(out)]
    stems = [out / episode_name(tiny(e)) for e in range(3)]
    proc = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                            start_new_session=True)
    deadline = time.monotonic() + 120
    while not any(read_complete(s, ("mcap",)) for s in stems) and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.02)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.communicate()
    finished = {s: s.with_suffix(".mcap").stat().st_mtime_ns for s in stems if read_complete(s, ("mcap",))}
    assert 0 < len(finished) < len(stems)  # killed midway
    done = subprocess.run(command, capture_output=True, text=True, timeout=240)
    assert done.returncode == 0, done.stderr
    assert [p.stem for p in episode_files(out)] == sorted(s.name for s in stems)
    assert all(read_complete(s, ("mcap",)) for s in stems)
    assert {s: s.with_suffix(".mcap").stat().st_mtime_ns for s in finished} == finished


def test_a_dead_worker_is_replaced_and_the_sweep_finishes(swept, tmp_path):
    """SIGKILL to one of two workers alone (as a crash) once an episode is complete, while the other is
    recording: the broken pool's other worker is killed (it outlived the pool and wrote the episodes run
    again), a fresh pool runs what the round left, and the sweep ends with every episode complete, exit
    status 0. Eight episodes of a few tenths of a second each, so that the poll finds a worker recording."""
    out = tmp_path / "runs"
    shutil.copytree(swept[0] / JAX_CACHE, out / JAX_CACHE)
    envs = 8
    stems = [out / episode_name(tiny(e)) for e in range(envs)]
    proc = subprocess.Popen([sys.executable, "-m", "scenarios.sweep", *TINY, "--max-steps", str(STEPS), "--envs",
                             str(envs), "--workers", "2", "--out", str(out)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)
    deadline = time.monotonic() + 120
    complete, workers = False, []  # the one to kill first (idle where one is), then one recording
    while len(workers) < 2 and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.01)
        complete = complete or any(read_complete(s, ("mcap",)) for s in stems)
        if complete:
            writing = {pid: recording_open(pid) for pid in spawned(proc.pid)}
            if len(writing) == 2 and any(writing.values()):
                workers = sorted(writing, key=writing.get)
    assert len(workers) == 2
    os.kill(workers[0], signal.SIGKILL)
    try:
        while not spawned(proc.pid) - set(workers) and time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.01)
        outlived = alive(workers[1])  # when the fresh pool starts
        _, stderr = proc.communicate(timeout=240)
    finally:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
    assert proc.returncode == 0, stderr
    assert re.search(r"a worker process died .*; \d episodes run again", stderr)
    assert all(read_complete(s, ("mcap",)) for s in stems)
    assert not outlived


def test_recycled_workers_finish_the_sweep(swept, tmp_path):
    """``--recycle 2`` replaces the worker once in 3 episodes (a pool's max_tasks_per_child hung at the first)."""
    out = tmp_path / "runs"
    shutil.copytree(swept[0] / JAX_CACHE, out / JAX_CACHE)
    argv = [*TINY, "--max-steps", "3", "--envs", "3", "--workers", "1", "--recycle", "2", "--out", str(out)]
    proc = subprocess.Popen([sys.executable, "-m", "scenarios.sweep", *argv], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)
    try:
        _, stderr = proc.communicate(timeout=240)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.communicate()
        pytest.fail("the sweep hung after its first worker was recycled")
    assert proc.returncode == 0, stderr
    assert all(read_complete(out / episode_name(tiny(e, max_steps=3)), ("mcap",)) for e in range(3))
    meta = load_run(out / "experiment.mcap").meta  # what made the folder, for the tables' captions
    assert (meta["scenario"], meta["experiment"], meta["settings"]["episodes"]) == ("experiment", "sweep", 3)
    assert meta["command"] == "python -m scenarios.sweep " + " ".join(argv)
    assert meta["machine"]["cores"] == os.cpu_count() and meta["machine"]["versions"]["jax"]


def test_a_worker_drops_its_compiled_programs_past_a_share_of_the_kernels_map_limit(monkeypatch, tmp_path):
    import jax

    if not Path("/proc/self/maps").exists():
        pytest.skip("no /proc: nothing to count")
    program = jax.jit(lambda x: x + 1.0)
    program(1.0)
    assert not release_programs(share=1e9) and program._cache_size() == 1  # far below: kept
    assert release_programs(share=0.0) and program._cache_size() == 0  # past it: dropped
    released = []
    monkeypatch.setattr(scenarios.sweep, "release_programs", lambda: released.append(True))
    monkeypatch.setattr(scenarios.episode, "run_episode", lambda *a, **k: 1 / 0)
    seconds, error, _ = run_one(tiny(0), str(tmp_path / "one"), ("mcap",))
    assert "division by zero" in error and released == [True]  # after a failed episode too


def test_a_worker_does_not_repeat_the_mesh_and_goal_warnings_the_sweeps_check_showed(monkeypatch, tmp_path):
    from scenarios.episode import GoalWarning
    from scenarios.mesh_check import MeshWarning

    def episode(*args, **kwargs):
        warnings.warn(MeshWarning("mesh 'part.stl' is open"))
        warnings.warn(GoalWarning("goal (9.0, 0.0, 0.0) is 9.00 m from the base: it cannot be reached"))
        warnings.warn(UserWarning("something else"))
        return SimpleNamespace(signal=None)

    monkeypatch.setattr(scenarios.episode, "run_episode", episode)
    with warnings.catch_warnings(record=True) as shown:
        warnings.simplefilter("always")
        assert run_one(tiny(0), str(tmp_path / "one"), ("mcap",))[1] is None
    assert [str(w.message) for w in shown] == ["something else"]


class _Ended(Exception):
    pass


@pytest.mark.parametrize("signame", ["SIGTERM", "SIGINT"])
def test_a_worker_whose_episode_a_signal_stopped_starts_no_other(monkeypatch, tmp_path, signame):
    """The sweep's SIGTERM reaches a worker's recorder, which closes its episode; the pool may have queued
    the next for it already: the worker must end there, not record an episode the sweep kills half-written."""
    ran, ended = [], []

    def episode(settings, **kwargs):
        ran.append(settings.env_seed)
        return SimpleNamespace(signal=signame if settings.env_seed == 1 else None)

    def end(signum):
        ended.append(signum)
        raise _Ended

    monkeypatch.setattr(scenarios.episode, "run_episode", episode)
    monkeypatch.setattr(scenarios.sweep, "_end_worker", end)
    monkeypatch.setattr(scenarios.sweep, "_SIGNALLED", [])
    for env in (0, 1):
        assert _local_episode(tiny(env), str(tmp_path / f"e{env}"), ("mcap",))[1] is None
    with pytest.raises(_Ended):
        _local_episode(tiny(2), str(tmp_path / "e2"), ("mcap",))
    assert ran == [0, 1] and ended == [signal.Signals[signame]]


def test_a_worker_ended_by_its_signal_dies_of_it():
    """:func:`_end_worker` in a process that ignores the signal (as a worker ignores Ctrl-C)."""
    code = ("import signal; from scenarios.sweep import _end_worker; signal.signal(signal.SIGINT, signal.SIG_IGN); "
            "_end_worker(signal.SIGINT); print('alive')")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert done.returncode == -signal.SIGINT and "alive" not in done.stdout
