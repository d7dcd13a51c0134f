"""`python -m recorder.inspect` on the files a run produces (closed, killed) and on bad input."""

from __future__ import annotations

import shutil
import subprocess
import sys

from recorder import Recorder
from recorder.synthetic import SyntheticRun, main as synthetic_main


def inspect(*files) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "recorder.inspect", *map(str, files)], capture_output=True, text=True)


def test_inspect_reports_meta_steps_outcome_and_completeness(tmp_path):
    assert synthetic_main([str(tmp_path / "run"), "--steps", "4", "--links", "2"]) == 0
    res = inspect(tmp_path / "run.rrd", tmp_path / "run.mcap")
    assert res.returncode == 0, res.stderr
    blocks = res.stdout.strip().split("\n" + str(tmp_path))
    assert len(blocks) == 2
    for block in blocks:
        assert 'run_id="run"' in block and "links=2" in block
        assert "steps: 4" in block
        assert "outcome: outcome=success, steps=4, reach_step=3" in block
        assert "complete: yes" in block


def test_inspect_reports_an_unclosed_file(tmp_path):
    """Snapshots taken after a flush, before closing: what a killed run leaves behind."""
    run = SyntheticRun(links=2, seed=0, rings=3, ring_points=4, n_points=5, horizon=3)
    with Recorder(tmp_path / "run", run.meta) as rec:
        for k in range(3):
            rec.log_step(k, 0.1 * k, **run.step(k))
        rec.flush()
        for suffix in (".rrd", ".mcap"):
            shutil.copy(tmp_path / f"run{suffix}", tmp_path / f"snap{suffix}")
    res = inspect(tmp_path / "snap.rrd", tmp_path / "snap.mcap")
    assert res.returncode == 0, res.stderr
    assert res.stdout.count("steps: 3") == 2 and res.stdout.count("outcome: none") == 2
    assert res.stdout.count("complete: no") == 2


def test_inspect_bad_files_exit_2_without_traceback(tmp_path):
    junk = tmp_path / "junk.rrd"
    junk.write_text("junk")
    res = inspect(junk, tmp_path / "missing.mcap")
    assert res.returncode == 2
    assert res.stderr.count("error: ") == 2 and str(junk) in res.stderr
    assert "Traceback" not in res.stderr


def test_inspect_help():
    res = inspect("--help")
    assert res.returncode == 0 and "FILE" in res.stdout
