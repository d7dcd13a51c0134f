"""What the two analysis scripts share on the command line: one-line errors, signals."""

from __future__ import annotations

import argparse
import contextlib
import signal
import sys

#: Exit status per signal: 128 + its number.
EXIT_STATUS = {signal.SIGINT: 130, signal.SIGTERM: 143}


class Parser(argparse.ArgumentParser):
    """argparse with one-line errors (``prog: error: ...``, exit 2) instead of usage + error."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message}\n")


class Stopped(BaseException):
    """SIGINT or SIGTERM arrived; ``signum`` says which."""

    def __init__(self, signum: int):
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


@contextlib.contextmanager
def stop_on_signals():
    """Inside the block, SIGINT and SIGTERM raise ``Stopped`` (the scripts write each file whole, so
    stopping between files keeps every file already written); the previous handlers come back after."""

    def stop(signum, frame):
        raise Stopped(signum)

    previous = {sig: signal.signal(sig, stop) for sig in EXIT_STATUS}
    try:
        yield
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def run_until_stopped(body, args, kept: str) -> int:
    """``body(args)``; on SIGINT or SIGTERM one line saying that the ``kept`` already written under
    ``args.out`` are kept, and the signal's exit status."""
    try:
        with stop_on_signals():
            return body(args)
    except Stopped as exc:
        print(f"stopped by {exc}: {kept} already written under {args.out} are kept", file=sys.stderr)
        return EXIT_STATUS[exc.signum]
