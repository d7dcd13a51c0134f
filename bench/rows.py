"""The row loop the table benches share (``broad_phase.py``, ``convex_clearance.py``,
``route_plan.py``), imported from their folder: each row printed as soon as it is measured,
and SIGINT or SIGTERM answered with one line and the signal's exit status."""

from __future__ import annotations

from typing import Callable, Iterable

from recorder.cli import stoppable


def print_rows(items: Iterable, lines: Callable[[object], Iterable[str]]) -> int:
    """Print the lines ``lines(item)`` gives for each item, flushed one by one; :func:`recorder.cli.stoppable`'s status
    (a signal stops the loop between two lines or inside a measurement)."""

    def body():
        for item in items:
            for line in lines(item):
                print(line, flush=True)

    return stoppable(body)
