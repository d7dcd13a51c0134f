"""Without rerun-sdk: the recorder, the episode runner and the benchmarks import, an .mcap-only
recording is written and reads back, and asking for an .rrd fails with one error naming the cause."""

import subprocess
import sys
import textwrap
from pathlib import Path

SCRIPT = textwrap.dedent("""
    import sys
    sys.modules["rerun"] = None  # import rerun -> ImportError, as where rerun-sdk is not installed
    sys.path.insert(0, sys.argv[2])
    import closed_loop, paper_timing, scenarios.episode
    from recorder import Recorder, RecorderError, load_run

    out = sys.argv[1]
    with Recorder(out + "/run", {{"seed": 0}}, formats=("mcap",)) as rec:
        rec.log_step(0, 0.0, metrics={{"solver_ms": 1.5}})
        rec.finish({{"outcome": "success", "steps": 1}})
    run = load_run(out + "/run.mcap")
    print(run.outcome["outcome"], run.metrics["solver_ms"].tolist(), run.complete)
    try:
        Recorder(out + "/other", {{"seed": 0}}, formats=("rrd",))
    except RecorderError as error:
        print("error:", error)
    print("rerun imported:", "rerun" in sys.modules and sys.modules["rerun"] is not None)
""")


def test_recording_mcap_needs_no_rerun(tmp_path):
    bench = Path(__file__).resolve().parents[2] / "bench"
    done = subprocess.run([sys.executable, "-c", SCRIPT.format(), str(tmp_path), str(bench)], capture_output=True,
                          text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    lines = done.stdout.splitlines()
    assert lines[0] == "success [1.5] True"
    assert lines[1].startswith(f"error: cannot open {tmp_path}/other.rrd") and "rerun" in lines[1]
    assert lines[2] == "rerun imported: False"
    assert not (tmp_path / "other.rrd").exists()
