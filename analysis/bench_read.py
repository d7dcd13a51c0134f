"""How long reading a folder of many recordings takes (the tables' first step).

    python analysis/bench_read.py [RECORDING] [--copies 4000]

Hard-links one recording ``--copies`` times into a temporary folder and times
``analysis.load.load`` over it without its cache (recorder.read.load_runs: metadata, metrics and
outcome), against a reference in the same run: ``recorder.load_run`` (which also parses the /state
topic) on the first 50 copies, one at a time. Prints seconds, files per second, the ratio per file,
and the time of a second read of the unchanged folder through the analysis cache.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
import warnings
from pathlib import Path

if __package__ in (None, ""):
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from analysis.load import load  # noqa: E402
from recorder import load_run  # noqa: E402

REFERENCE_FILES = 50


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python analysis/bench_read.py", description=__doc__.split("\n\n")[0])
    p.add_argument("recording", nargs="?", help="an .mcap recording (default: the first one under runs/)")
    p.add_argument("--copies", type=int, default=4000)
    args = p.parse_args(argv)
    source = Path(args.recording) if args.recording else next(iter(sorted(Path("runs").rglob("*.mcap"))), None)
    if source is None or not source.is_file() or args.copies < 1:
        print(f"error: need an existing .mcap recording and --copies >= 1 (got {source}, {args.copies})",
              file=sys.stderr)
        return 2
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(args.copies):
            os.link(source, Path(tmp) / f"copy{i:05d}.mcap")
        start = time.perf_counter()
        rec = load(tmp, cache=False)
        seconds = time.perf_counter() - start
        os.environ["NCEDF_CACHE"] = str(Path(tmp) / "cache")  # a cache of this run only
        load(tmp)
        start = time.perf_counter()
        load(tmp)
        cached = time.perf_counter() - start
        ref_files = sorted(Path(tmp).glob("*.mcap"))[:REFERENCE_FILES]
        start = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            for path in ref_files:
                load_run(path)
        ref = (time.perf_counter() - start) / len(ref_files)
    size = source.stat().st_size / 1e6
    per = seconds / args.copies
    print(f"{args.copies} copies of {source.name} ({size:.1f} MB, {len(rec.steps) // max(1, len(rec.runs))} steps): "
          f"read in {seconds:.1f} s ({args.copies / seconds:.0f} files/s, {1e3 * per:.1f} ms per file); "
          f"reference load_run with state: {1e3 * ref:.1f} ms per file (ratio {ref / per:.2f}); "
          f"again, nothing changed (analysis cache): {cached:.2f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
