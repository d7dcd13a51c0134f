"""Start-up time of the user's commands: a first run (empty compilation cache) against a second.

Each command runs in a fresh process with its own empty ``$NCEDF_CACHE`` (so the datasets are
not cached either: the evaluation builds its validation set both times), first with ``--no-cache``
(today's start-up without the persistent compilation cache, ``ncedf.compile_cache``), then twice
with it: the first fills the cache, the second reads it. A runner takes one MPPI step; besides the
whole command's time, the time from the start to the end of its first control step is printed
(``first step``: the command runs under a probe that notes when ``Controller.step`` first returns).

    python bench/startup.py [--commands cluttered7,cluttered4,evaluate]
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from arguments import parse_list
from recorder.cli import OneLineParser, exit_with, stoppable

COMMANDS = {
    "cluttered7": ["-m", "scenarios.cluttered", "--links", "7", "--max-steps", "1", "--formats", "mcap"],
    "cluttered4": ["-m", "scenarios.cluttered", "--links", "4", "--max-steps", "1", "--formats", "mcap"],
    "evaluate": ["-m", "ncedf.evaluate", "--configs", "10", "--points", "512"],
}


#: Runs ``python -m MODULE ARGS`` (argv[1:]) and prints the wall clock when the first control step returns.
PROBE = """
import runpy, sys, time
import ncedf.controller as controller
step = controller.Controller.step
def first(self, *args, **kwargs):
    out = step(self, *args, **kwargs)
    controller.Controller.step = step
    print(f"FIRST STEP {time.time()!r}", file=sys.stderr, flush=True)
    return out
controller.Controller.step = first
sys.argv = sys.argv[1:]
runpy.run_module(sys.argv[0], run_name="__main__", alter_sys=True)
"""


def timed(argv: list[str], cache: Path, extra: list[str], out: Path) -> tuple[float, float | None]:
    """Wall seconds of ``python argv + extra`` with ``$NCEDF_CACHE`` = cache, and of its start to the end
    of its first control step (None for a command that takes none); raises if it fails."""
    runner = "--max-steps" in argv
    outputs = ["--out", str(out), "--overwrite"] if runner else []
    env = {k: v for k, v in os.environ.items() if k != "JAX_COMPILATION_CACHE_DIR"} | {"NCEDF_CACHE": str(cache)}
    command = [sys.executable, "-c", PROBE, *argv[1:]] if argv[0] == "-m" else [sys.executable, *argv]
    start, wall = time.perf_counter(), time.time()
    done = subprocess.run([*command, *outputs, *extra], env=env, capture_output=True, text=True)
    seconds = time.perf_counter() - start
    if done.returncode != 0:
        raise SystemExit(f"{' '.join(argv)} failed ({done.returncode}): {done.stderr.strip().splitlines()[-1:]}")
    mark = re.search(r"FIRST STEP (\S+)", done.stderr)  # anywhere: a progress bar may share its line
    return seconds, (float(mark.group(1)) - wall if mark else None)


def _seconds(value: float | None) -> str:
    return "-" if value is None else f"{value:.1f}"


def main() -> None:
    p = OneLineParser(prog="python bench/startup.py", description=__doc__.split("\n\n")[0])
    p.add_argument("--commands", type=lambda t: parse_list(t, str, "command", tuple(COMMANDS)),
                   default=list(COMMANDS), help=f"comma-separated, from {', '.join(COMMANDS)} (default all)")
    args = p.parse_args()
    print(f"{'command':12s} {'':>10s} {'no cache s':>11s} {'first s':>8s} {'second s':>9s} {'second/no cache':>16s}")
    with tempfile.TemporaryDirectory() as tmp:
        for name in args.commands:
            argv, folder = COMMANDS[name], Path(tmp) / name
            cold = timed(argv, folder / "off", ["--no-cache"], folder / "run")
            first = timed(argv, folder / "on", [], folder / "run")
            second = timed(argv, folder / "on", [], folder / "run")
            for i, what in enumerate(("whole", "first step")):
                if second[i] is not None:
                    print(f"{name:12s} {what:>10s} {_seconds(cold[i]):>11s} {_seconds(first[i]):>8s} "
                          f"{_seconds(second[i]):>9s} {second[i] / cold[i]:16.2f}", flush=True)


if __name__ == "__main__":
    exit_with(stoppable(main))
