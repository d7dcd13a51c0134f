"""Tables I-IV of the paper from a folder of recordings: Markdown (printed), LaTeX and CSV.

    python analysis/make_tables.py [RUNS] [--out tables/]

Reads every recording under RUNS (default runs/, or the current folder where there is none, as
after ``python -m scenarios.cluttered``) through ``recorder.read``; each table puts the
paper's figures beside ours. A table whose recordings are missing is skipped with a line naming
the command that produces them; unreadable, unclosed or unfinished recordings are listed and
left out. A folder with no recordings at all is refused (exit status 2, nothing written).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

if __package__ in (None, ""):  # run as a script: make the repository importable
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from analysis.cli import run_until_stopped  # noqa: E402
from analysis.load import load, recordings_folder  # noqa: E402
from analysis.tables import BUILDERS  # noqa: E402
from recorder import RecorderError  # noqa: E402
from recorder.cli import OneLineParser, exit_with, path_text  # noqa: E402
from recorder.recorder import check_creatable  # noqa: E402


def parse_args(argv=None) -> argparse.Namespace:
    p = OneLineParser(prog="python analysis/make_tables.py", description=__doc__.split("\n\n")[0])
    p.add_argument("runs", nargs="?", default=None,
                   help="folder of recordings (default runs/, or the current folder where there is none)")
    p.add_argument("--out", default="tables", type=path_text, help="output folder (default tables/)")
    return p.parse_args(argv)


def report_problems(rec, stream=sys.stderr) -> None:
    if rec.problems:
        print(f"left out {len(rec.problems)} recording(s):", file=stream)
        for path, why in rec.problems:
            print(f"  {path}: {why}", file=stream)


def main(argv=None) -> int:
    return run_until_stopped(_main, parse_args(argv), "tables")


def _main(args) -> int:
    try:
        args.runs = recordings_folder(args.runs)
        check_creatable(args.out, "tables")
        rec = load(args.runs)
        if rec.files == 0:
            raise RecorderError(f"no recordings (.mcap, .rrd) under {args.runs}; make them with a scenario, a sweep "
                                "or `python -m scenarios.reproduce`")
    except RecorderError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    out = Path(args.out)  # checked before the recordings were read; made once there is something to write
    out.mkdir(parents=True, exist_ok=True)
    print(f"read {rec.files} recordings under {args.runs} in {rec.seconds:.2f} s "
          f"({len(rec.runs)} runs used)", file=sys.stderr)
    report_problems(rec)
    for name, build in BUILDERS.items():
        table = build(rec)
        if isinstance(table, str):
            print(table, file=sys.stderr)
            continue
        paths = table.write(out)
        print(table.markdown())
        print(f"wrote {', '.join(str(p) for p in paths)}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    exit_with(main())
