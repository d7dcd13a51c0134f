"""How long reading a folder of many recordings takes (the tables' first step).

    python analysis/bench_read.py [RECORDING] [--copies 400]

Hard-links one recording ``--copies`` times into a temporary folder and times
``recorder.load_summaries`` over it (what the tables read: from a closed .mcap's summary record,
footer and summary section only) against a reference in the same run: ``recorder.load_runs`` over
the same folder (every chunk opened for the /metrics and /outcome messages). Prints seconds, ms per
file, both extrapolated to 4000 recordings, and the ratio. A recording written before the summary
record existed is read in full by both (the line says so).
"""

from __future__ import annotations

import os
import sys
import tempfile
import time
from pathlib import Path

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from recorder import load_runs, load_summaries, mcap_scan, summary  # noqa: E402
from recorder.cli import OneLineParser, exit_with, stoppable  # noqa: E402

TARGET = 4000


def _timed(fn, folder) -> tuple[float, object]:
    start = time.perf_counter()
    out = fn(folder)
    return time.perf_counter() - start, out


def main(argv=None) -> int:
    p = OneLineParser(prog="python analysis/bench_read.py", description=__doc__.split("\n\n")[0])
    p.add_argument("recording", nargs="?", help="an .mcap recording (default: the first one under runs/)")
    p.add_argument("--copies", type=int, default=400)
    args = p.parse_args(argv)
    source = Path(args.recording) if args.recording else next(iter(sorted(Path("runs").rglob("*.mcap"))), None)
    if source is None or not source.is_file() or source.suffix != ".mcap" or args.copies < 1:
        print(f"error: need an existing .mcap recording and --copies >= 1 (got {source}, {args.copies})",
              file=sys.stderr)
        return 2
    has_record = summary.RECORD in (mcap_scan.indexed_metadata(source) or {})
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(args.copies):
            os.link(source, Path(tmp) / f"copy{i:05d}.mcap")
        fast, table = _timed(load_summaries, tmp)
        full, (runs, steps) = _timed(load_runs, tmp)
    assert len(table) == len(runs) == args.copies
    n = args.copies
    print(f"{n} copies of {source.name} ({source.stat().st_size / 1e6:.1f} MB, {len(steps) // n} steps, "
          f"{'with' if has_record else 'WITHOUT'} the summary record):")
    print(f"  load_summaries: {fast:.2f} s, {1e3 * fast / n:.2f} ms per file, "
          f"{TARGET} files ~ {TARGET * fast / n:.1f} s")
    print(f"  load_runs (reference): {full:.2f} s, {1e3 * full / n:.2f} ms per file, "
          f"{TARGET} files ~ {TARGET * full / n:.1f} s")
    print(f"  ratio load_runs / load_summaries: {full / fast:.0f}x")
    return 0


if __name__ == "__main__":
    exit_with(stoppable(main))
