"""Start-up time of the user's commands: a first run (empty compilation cache) against a second.

Each command runs in a fresh process with its own empty ``$NCEDF_CACHE`` (so the datasets are
not cached either: the evaluation builds its validation set both times), first with ``--no-cache``
(today's start-up without the persistent compilation cache, ``ncedf.compile_cache``), then twice
with it: the first fills the cache, the second reads it. A runner takes one MPPI step, so its time
bounds the time to its first step from above.

    python bench/startup.py [--commands cluttered7,cluttered4,evaluate]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from arguments import parse_list

COMMANDS = {
    "cluttered7": ["-m", "scenarios.cluttered", "--links", "7", "--max-steps", "1", "--formats", "mcap"],
    "cluttered4": ["-m", "scenarios.cluttered", "--links", "4", "--max-steps", "1", "--formats", "mcap"],
    "evaluate": ["-m", "ncedf.evaluate", "--configs", "10", "--points", "512"],
}


def timed(argv: list[str], cache: Path, extra: list[str], out: Path) -> float:
    """Wall seconds of ``python argv + extra`` with ``$NCEDF_CACHE`` = cache; raises if it fails."""
    runner = "--max-steps" in argv
    outputs = ["--out", str(out), "--overwrite"] if runner else []
    env = {**os.environ, "NCEDF_CACHE": str(cache)}
    start = time.perf_counter()
    done = subprocess.run([sys.executable, *argv, *outputs, *extra], env=env, capture_output=True, text=True)
    seconds = time.perf_counter() - start
    if done.returncode != 0:
        raise SystemExit(f"{' '.join(argv)} failed ({done.returncode}): {done.stderr.strip().splitlines()[-1:]}")
    return seconds


def main() -> None:
    p = argparse.ArgumentParser(prog="python bench/startup.py", description=__doc__.split("\n\n")[0])
    p.add_argument("--commands", type=lambda t: parse_list(t, str, "command", tuple(COMMANDS)),
                   default=list(COMMANDS), help=f"comma-separated, from {', '.join(COMMANDS)} (default all)")
    args = p.parse_args()
    print(f"{'command':12s} {'no cache s':>11s} {'first s':>8s} {'second s':>9s} {'second/no cache':>16s}")
    with tempfile.TemporaryDirectory() as tmp:
        for name in args.commands:
            argv, folder = COMMANDS[name], Path(tmp) / name
            cold = timed(argv, folder / "off", ["--no-cache"], folder / "run")
            first = timed(argv, folder / "on", [], folder / "run")
            second = timed(argv, folder / "on", [], folder / "run")
            print(f"{name:12s} {cold:11.1f} {first:8.1f} {second:9.1f} {second / cold:16.2f}", flush=True)


if __name__ == "__main__":
    main()
