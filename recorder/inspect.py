"""`python -m recorder.inspect FILE...`: per recording, its metadata, step count, outcome and completeness.

Exit status 0 when every file was read, 2 when any could not be (its line says `error: ...`).
"""

from __future__ import annotations

import json
import sys
import warnings

from recorder.errors import RecorderError
from recorder.read import IncompleteRecordingWarning, load_run


def describe(path: str) -> str:
    """A few lines about one recording (raises `RecorderError` if it cannot be read)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", IncompleteRecordingWarning)
        run = load_run(path)
    meta = ", ".join(f"{k}={json.dumps(v, sort_keys=True)}" for k, v in run.meta.items()) or "(none)"
    if run.outcome is None:
        outcome = "none (the run did not finish)"
    else:
        outcome = ", ".join(f"{k}={v}" for k, v in run.outcome.items())
    complete = "yes" if run.complete else "no: the file was not closed (run killed?); flushed steps are readable"
    return "\n".join([
        f"{path} ({run.format})",
        f"  run: {meta}",
        f"  steps: {len(run.metrics)}",
        f"  outcome: {outcome}",
        f"  complete: {complete}",
    ])


def main(argv: list[str] | None = None) -> int:
    from recorder.cli import OneLineParser
    parser = OneLineParser(prog="python -m recorder.inspect", description=__doc__.split("\n\n")[0])
    parser.add_argument("files", nargs="+", metavar="FILE", help=".rrd or .mcap recordings")
    args = parser.parse_args(argv)
    status = 0
    for path in args.files:
        try:
            print(describe(path))
        except RecorderError as exc:
            print(f"error: {exc}", file=sys.stderr)
            status = 2
    return status


if __name__ == "__main__":
    from recorder.cli import exit_with

    exit_with(main())
