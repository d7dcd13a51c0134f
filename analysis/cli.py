"""What the two analysis scripts share on the command line: stop on a signal between files."""

from __future__ import annotations

import sys

from recorder.cli import EXIT_STATUS, Stopped, stop_on_signals


def run_until_stopped(body, args, kept: str) -> int:
    """``body(args)``; on SIGINT or SIGTERM one line saying that the ``kept`` already written under
    ``args.out`` are kept, and the signal's exit status."""
    try:
        with stop_on_signals():
            return body(args)
    except Stopped as exc:
        print(f"stopped by {exc}: {kept} already written under {args.out} are kept", file=sys.stderr)
        return EXIT_STATUS[exc.signum]
