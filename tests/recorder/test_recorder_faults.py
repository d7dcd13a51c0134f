"""Faults: signals (SIGTERM in a subprocess, SIGKILL), exceptions, bad paths and bad files."""

from __future__ import annotations

import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from recorder import IncompleteRecordingWarning, Recorder, RecorderError, load_run
from recorder.synthetic import SyntheticRun
from recorder.synthetic import main as synthetic_main

RERUN = str(Path(sys.executable).with_name("rerun"))
FLUSH_EVERY, KILL_AFTER_STEP = 10, 25


def run_until(out: Path, sig: int) -> int:
    """Start a long synthetic run, send `sig` once it printed step KILL_AFTER_STEP, return its exit code."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "recorder.synthetic", str(out), "--steps", "100000", "--step-delay", "0.01",
         "--print-steps", "--flush-every", str(FLUSH_EVERY)],
        stdout=subprocess.PIPE, text=True,
    )
    for line in proc.stdout:
        if line.strip() == f"step {KILL_AFTER_STEP}":
            break
    proc.send_signal(sig)
    proc.stdout.close()
    return proc.wait(timeout=60)


def check_values(metrics: pd.DataFrame) -> None:
    """Every row read back is the synthetic step that was sent (seed 0, 4 links, dt 0.05)."""
    run = SyntheticRun(links=4, seed=0)
    assert metrics["step"].tolist() == list(range(len(metrics)))
    for k, row in metrics.iterrows():
        sent = run.step(k)["metrics"]
        assert row[list(sent)].tolist() == list(sent.values())
        assert row["sim_time"] == round(k * 0.05 * 1e9) / 1e9  # sim_time is stored to 1 ns


def verify_rrd(path: Path) -> int:
    return subprocess.run([RERUN, "rrd", "verify", str(path)], capture_output=True).returncode


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_signal_finishes_the_step_and_closes_both_files(tmp_path, sig):
    out = tmp_path / "term"
    assert run_until(out, sig) == 128 + sig  # 130 after SIGINT, 143 after SIGTERM
    assert verify_rrd(out.with_suffix(".rrd")) == 0
    runs = [load_run(out.with_suffix(s)) for s in (".rrd", ".mcap")]
    for r in runs:
        assert r.complete
        assert r.outcome["outcome"] == "interrupted"
        assert r.outcome["steps"] == len(r.metrics) == len(r.state) > KILL_AFTER_STEP
        check_values(r.metrics)
    pd.testing.assert_frame_equal(runs[0].metrics, runs[1].metrics)
    pd.testing.assert_frame_equal(runs[0].state, runs[1].state)


def test_sigkill_loses_at_most_the_last_flush_interval(tmp_path):
    out = tmp_path / "kill"
    assert run_until(out, signal.SIGKILL) == -signal.SIGKILL
    assert verify_rrd(out.with_suffix(".rrd")) != 0
    flushed = (KILL_AFTER_STEP + 1) // FLUSH_EVERY * FLUSH_EVERY  # steps up to the last flush before the kill
    for suffix in (".rrd", ".mcap"):
        with pytest.warns(IncompleteRecordingWarning, match="was not closed"):
            r = load_run(out.with_suffix(suffix))
        assert not r.complete and r.outcome is None
        assert r.meta["run_id"] == "kill"
        assert len(r.metrics) >= flushed
        check_values(r.metrics)


def test_exception_inside_the_block_writes_interrupted(tmp_path):
    run = SyntheticRun(links=2, seed=0, rings=3, ring_points=4, n_points=5, horizon=3)
    with pytest.raises(ZeroDivisionError):
        with Recorder(tmp_path / "x", run.meta) as rec:
            rec.log_step(0, 0.0, **run.step(0))
            rec.log_step(1, 0.1, **run.step(1))
            1 / 0
    for suffix in (".rrd", ".mcap"):
        r = load_run(tmp_path / f"x{suffix}")
        assert r.complete
        assert r.outcome == {"outcome": "interrupted", "steps": 2, "reach_step": None,
                             "min_true_distance": min(run.step(k)["metrics"]["true_min_distance"] for k in (0, 1)),
                             "first_collision_step": None}


def test_signal_handlers_only_while_open(tmp_path):
    before = signal.getsignal(signal.SIGTERM), signal.getsignal(signal.SIGINT)
    rec = Recorder(tmp_path / "h", {})
    assert signal.getsignal(signal.SIGTERM) not in before
    rec.finish({"outcome": "stuck"})
    assert (signal.getsignal(signal.SIGTERM), signal.getsignal(signal.SIGINT)) == before


def test_cli_refuses_an_existing_output_without_overwrite(tmp_path, capsys):
    out = str(tmp_path / "run")
    assert synthetic_main([out, "--steps", "1"]) == 0
    assert synthetic_main([out, "--steps", "1"]) == 2
    expected = f"error: {out}.rrd exists; pass overwrite=True (--overwrite) to replace it"
    assert capsys.readouterr().err.strip() == expected
    assert synthetic_main([out, "--steps", "2", "--overwrite"]) == 0
    assert len(load_run(out + ".mcap").metrics) == 2


def test_existing_output_is_not_overwritten(tmp_path):
    (tmp_path / "run.mcap").write_bytes(b"keep me")
    with pytest.raises(RecorderError, match=str(tmp_path / "run.mcap")):
        Recorder(tmp_path / "run", {})
    assert not (tmp_path / "run.rrd").exists()
    assert (tmp_path / "run.mcap").read_bytes() == b"keep me"
    with Recorder(tmp_path / "run", {}, overwrite=True) as rec:
        rec.log_step(0, 0.0, metrics={"goal_distance": 1.0})
    assert load_run(tmp_path / "run.mcap").metrics["goal_distance"].tolist() == [1.0]


def test_a_folder_in_an_outputs_place_fails_before_anything_is_opened(tmp_path):
    (tmp_path / "run.mcap").mkdir()
    with pytest.raises(RecorderError, match=f"{tmp_path / 'run.mcap'} is a folder"):
        Recorder(tmp_path / "run", {}, overwrite=True)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["run.mcap"]


def test_unwritable_folder_fails_before_anything_is_opened(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("")
    with pytest.raises(RecorderError, match=f"cannot write recordings to {blocker / 'sub'}"):
        Recorder(blocker / "sub" / "run", {})


def test_bad_arguments_raise_clear_errors(tmp_path):
    with pytest.raises(ValueError, match="reserved"):
        Recorder(tmp_path / "a", {"outcome": 1})
    with pytest.raises(ValueError, match="not JSON-serialisable"):
        Recorder(tmp_path / "a", {"x": object()})
    run = SyntheticRun(links=2, seed=0, rings=3, ring_points=4, n_points=5, horizon=3)
    with Recorder(tmp_path / "b", {}) as rec:
        step = run.step(0)
        rec.log_step(0, 0.0, **step)
        with pytest.raises(ValueError, match="mesh topology changed"):
            rec.log_step(1, 0.1, **{**step, "mesh_triangles": step["mesh_triangles"][:-1]})
        with pytest.raises(ValueError, match="steps must increase"):
            rec.log_step(0, 0.1, metrics={})
        with pytest.raises(ValueError, match="state arc_lengths"):
            rec.log_step(1, 0.1, metrics={}, state={**step["state"], "arc_lengths": np.zeros((3, 3))})
        with pytest.raises(ValueError, match="outcome must be one of"):
            rec.finish({"outcome": "won"})


@pytest.mark.parametrize("content", [b"", b"not a recording at all"])
@pytest.mark.parametrize("suffix", [".rrd", ".mcap"])
def test_garbage_files_give_a_recorder_error(tmp_path, content, suffix):
    path = tmp_path / f"junk{suffix}"
    path.write_bytes(content)
    with pytest.raises(RecorderError, match=str(path)):
        load_run(path)


def test_missing_and_foreign_files(tmp_path):
    with pytest.raises(RecorderError, match="does not exist"):
        load_run(tmp_path / "nope.rrd")
    (tmp_path / "a.txt").write_text("x")
    with pytest.raises(RecorderError, match="expected a .rrd or .mcap"):
        load_run(tmp_path / "a.txt")
