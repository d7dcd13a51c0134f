"""Command-line conventions every command of the project shares (scenario runners, sweeps,
reproduce, analysis): one-line argument errors and warnings, and SIGINT / SIGTERM raised as
``Stopped`` with exit status 130 / 143. Here because ``recorder`` is the one package every command depends on."""

from __future__ import annotations

import argparse
import contextlib
import os
import signal
import sys
import warnings
from typing import Callable, NoReturn

from recorder.errors import RecordingInterrupted

#: Exit status per signal: 128 + its number.
EXIT_STATUS = {signal.SIGINT: 130, signal.SIGTERM: 143}


class OneLineParser(argparse.ArgumentParser):
    """argparse with one-line errors (``prog: error: ...``, exit 2) instead of usage + error."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message}\n")


def path_text(text: str) -> str:
    """An argparse type: a path, not the empty string (which names the current folder, or a file
    stem with no name)."""
    if not text.strip():
        raise argparse.ArgumentTypeError(f"must name a path, got {text!r}")
    return text


def _integer(text: str, low: int) -> int:
    """An integer >= ``low``."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
    if value < low:
        raise argparse.ArgumentTypeError(f"must be >= {low}, got {value}")
    return value


def positive(text: str) -> int:
    """An argparse type: an integer >= 1 (a count that must not be empty)."""
    return _integer(text, 1)


def non_negative(text: str) -> int:
    """An argparse type: an integer >= 0."""
    return _integer(text, 0)


@contextlib.contextmanager
def one_line_warnings(once=()):
    """Inside the block, warnings are shown as ``warning: message`` on stderr (not Python's source
    location and line), and those of the categories ``once`` only the first time their text comes.
    (Not the filters' "once": a change of the filters, as any ``catch_warnings`` makes, forgets it.)"""
    shown = set()

    def show(message, category, filename, lineno, file=None, line=None):
        if issubclass(category, tuple(once)):
            if str(message) in shown:
                return
            shown.add(str(message))
        print(f"warning: {message}", file=sys.stderr)

    with warnings.catch_warnings():
        warnings.showwarning = show
        yield


class Stopped(BaseException):
    """SIGINT or SIGTERM arrived; ``signum`` says which."""

    def __init__(self, signum: int):
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


@contextlib.contextmanager
def stop_on_signals():
    """Inside the block, SIGINT and SIGTERM raise :class:`Stopped`; the previous handlers come back after."""

    def stop(signum, frame):
        raise Stopped(signum)

    previous = {sig: signal.signal(sig, stop) for sig in EXIT_STATUS}
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def stoppable(body: Callable[[], int | None], kept: str = "the rows above are complete") -> int:
    """``body()``'s status (None: 0), or 130 / 143 after SIGINT / SIGTERM (:func:`stop_on_signals`, or a
    recording's own handler) with one line on stderr saying what was ``kept``: a benchmark's stop."""
    try:
        with stop_on_signals():
            return body() or 0
    except (Stopped, RecordingInterrupted) as stop:
        print(f"interrupted ({signal.Signals(stop.signum).name}): {kept}", file=sys.stderr)
        return EXIT_STATUS[stop.signum]


def exit_with(status: int) -> NoReturn:
    """Leave the process with ``status``: the last call of every command's ``__main__``.

    After a stop (a status of ``EXIT_STATUS``) the interpreter's teardown is skipped
    (``os._exit``, with the standard streams flushed): a signal that arrives while XLA
    compiles raises ``Stopped`` out of the compilation and leaves its threads running, and
    the teardown then crashes (a segmentation fault or an abort) instead of exiting with the
    status. A command has closed its files by the time it returns the status.
    """
    if status in EXIT_STATUS.values():
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(status)
    sys.exit(status)
