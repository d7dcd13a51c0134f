"""The row loop the table benches share (``broad_phase.py``, ``convex_clearance.py``,
``route_plan.py``), imported from their folder: each row printed as soon as it is measured,
and SIGINT or SIGTERM answered with one line and the signal's exit status."""

from __future__ import annotations

import sys
from typing import Callable, Iterable

from recorder.cli import EXIT_STATUS, Stopped, stop_on_signals


def print_rows(items: Iterable, lines: Callable[[object], Iterable[str]]) -> int:
    """Print the lines ``lines(item)`` gives for each item, flushed one by one.

    Returns 0, or 130 / 143 after SIGINT / SIGTERM, which stop the loop between
    two lines or inside a measurement (``recorder.cli.stop_on_signals``); the
    printed rows are complete, and stderr says so in one line.
    """
    try:
        with stop_on_signals():
            for item in items:
                for line in lines(item):
                    print(line, flush=True)
    except Stopped as stop:
        print(f"interrupted ({stop}): the rows above are complete", file=sys.stderr)
        return EXIT_STATUS[stop.signum]
    return 0
