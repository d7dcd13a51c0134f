"""The paper's figures from a folder of recordings: PNG, with the plotted data as CSV beside each.

    python analysis/make_figures.py [RUNS] [--out figures/] [--model PATH]

Fig. 3 (N-CEDF slices, learned beside exact; the model is evaluated, --model or the shipped one),
Fig. 4 (distances over time in one dynamic-sphere run), Figs. 5-7 (4/5/7-link cluttered runs at
the paper's steps and the reach step, drawn from the recorded geometry), MPPI step time against
link count and against obstacle-point count, and success rates with Wilson 95% intervals.
A figure whose recordings are missing is skipped with a line naming the command that makes them.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

if __package__ in (None, ""):  # run as a script: make the repository importable
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from analysis.cli import run_until_stopped  # noqa: E402
from analysis.load import load, recordings_folder  # noqa: E402
from analysis.make_tables import report_problems  # noqa: E402
from recorder import RecorderError  # noqa: E402
from recorder.cli import OneLineParser, exit_with, path_text  # noqa: E402
from recorder.recorder import check_folder  # noqa: E402


def parse_args(argv=None) -> argparse.Namespace:
    p = OneLineParser(prog="python analysis/make_figures.py", description=__doc__.split("\n\n")[0])
    p.add_argument("runs", nargs="?", default=None,
                   help="folder of recordings (default runs/, or the current folder where there is none)")
    p.add_argument("--out", default="figures", type=path_text, help="output folder (default figures/)")
    p.add_argument("--model", type=path_text, help="N-CEDF weights for Fig. 3 (default: the shipped model)")
    return p.parse_args(argv)


def main(argv=None) -> int:
    return run_until_stopped(_main, parse_args(argv), "figures")


def _main(args) -> int:
    try:
        args.runs = recordings_folder(args.runs)
        if args.model is not None and not Path(args.model).with_suffix(".msgpack").is_file():
            raise RecorderError(f"model {args.model} not found (expected {Path(args.model).with_suffix('.msgpack')})")
        out = check_folder(args.out, "figures")
        rec = load(args.runs)
    except RecorderError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    import matplotlib.pyplot as plt

    from analysis.figures import builders

    print(f"read {rec.files} recordings under {args.runs} in {rec.seconds:.2f} s", file=sys.stderr)
    report_problems(rec)
    for name, build in builders(rec, args.model):
        try:
            result = build()
        except RecorderError as exc:
            print(f"{name}: skipped, {exc}", file=sys.stderr)
            continue
        if isinstance(result, str):
            print(result, file=sys.stderr)
            continue
        fig, data = result
        fig.savefig(out / f"{name}.png")
        plt.close(fig)
        data.to_csv(out / f"{name}.csv", index=False, float_format="%.6g")
        print(f"wrote {out / name}.png and .csv", file=sys.stderr)
    return 0


if __name__ == "__main__":
    exit_with(main())
