"""The README's user's day, run as printed (with small settings) in an empty folder: a runner writes
``recording.rrd`` and ``recording.mcap`` there, the viewer's file reads back, and the tables
command with no argument finds the recording and gives its Table IV row."""

import subprocess
import sys
from pathlib import Path

import pandas as pd

from recorder import load_run

RERUN = str(Path(sys.executable).with_name("rerun"))
SMALL = ["--links", "4", "--samples", "16", "--horizon", "4", "--max-steps", "3"]


def test_the_users_day_in_an_empty_folder(tmp_path):
    def command(*argv):
        return subprocess.run(argv, cwd=tmp_path, capture_output=True, text=True, timeout=600)

    done = command(sys.executable, "-m", "scenarios.cluttered", *SMALL)
    assert done.returncode == 0, done.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["recording.mcap", "recording.rrd"]
    assert command(RERUN, "rrd", "verify", "recording.rrd").returncode == 0  # what `rerun recording.rrd` opens
    done = command(sys.executable, "-m", "analysis.make_tables")
    assert done.returncode == 0, done.stderr
    row = pd.read_csv(tmp_path / "tables" / "table4.csv").iloc[0]
    run = load_run(tmp_path / "recording.mcap")
    assert (row["links"], row["episodes"]) == (4, 1)
    assert row["n_success"] == (run.outcome["outcome"] == "success")
