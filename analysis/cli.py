"""What the two analysis scripts share on the command line: their output folder, checked before any
recording is read; a stop on a signal between files."""

from __future__ import annotations

import sys
import tempfile
from pathlib import Path

from recorder import RecorderError
from recorder.cli import EXIT_STATUS, Stopped, stop_on_signals


def output_folder(out) -> Path:
    """The folder ``out``, made where missing; RecorderError (one line) where it cannot hold new files."""
    out = Path(out)
    try:
        out.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=out):
            pass
    except OSError as exc:
        raise RecorderError(f"cannot write to the output folder {out}: {exc.strerror or exc}") from None
    return out


def run_until_stopped(body, args, kept: str) -> int:
    """``body(args)``; on SIGINT or SIGTERM one line saying that the ``kept`` already written under
    ``args.out`` are kept, and the signal's exit status."""
    try:
        with stop_on_signals():
            return body(args)
    except Stopped as exc:
        print(f"stopped by {exc}: {kept} already written under {args.out} are kept", file=sys.stderr)
        return EXIT_STATUS[exc.signum]
