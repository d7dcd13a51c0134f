"""Command-line argument types the benches share, imported from their folder (the counts' types,
``positive`` and ``non_negative``, are the commands' own from ``recorder.cli``). They raise
``argparse.ArgumentTypeError``, which the parser reports in one line naming the option."""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from recorder.cli import non_negative, positive

__all__ = ["link_counts", "non_negative", "output_file", "parse_list", "positive", "positive_float", "runs_folder"]


def parse_list(text: str, cast, name: str, allowed=None, above_zero: bool = False) -> list:
    """The comma-separated values of ``text``, each ``cast``; non-empty, each in ``allowed`` if given,
    and each > 0 if ``above_zero``."""
    try:
        values = [cast(v) for v in text.split(",") if v]
    except ValueError:
        raise argparse.ArgumentTypeError(f"bad {name} list {text!r}") from None
    if not values:
        raise argparse.ArgumentTypeError(f"empty {name} list")
    bad = [v for v in values if allowed is not None and v not in allowed]
    if bad:
        raise argparse.ArgumentTypeError(f"unknown {name} {bad[0]!r}; choose from {', '.join(map(str, allowed))}")
    if above_zero and not all(0 < v < math.inf for v in values):
        raise argparse.ArgumentTypeError(f"{name} must be finite and > 0, got {text!r}")
    return values


def link_counts(text: str) -> list[int]:
    """The link counts of the paper's cluttered scene in ``text`` (a subset of 4, 5, 7)."""
    return parse_list(text, int, "link count", (4, 5, 7))


def output_file(text: str) -> Path:
    """A file to write at the end: not a folder, in a folder that exists (checked before the work)."""
    path = Path(text)
    if not text.strip() or path.is_dir() or not path.parent.is_dir():
        raise argparse.ArgumentTypeError(f"cannot write {text!r} (a folder, or in a folder that does not exist)")
    return path


def runs_folder(text: str) -> Path:
    """An existing folder that holds recordings."""
    from recorder.read import find_recordings

    path = Path(text)
    if not text.strip() or not path.is_dir():
        raise argparse.ArgumentTypeError(f"no such folder: {text!r}")
    if not find_recordings(path):
        raise argparse.ArgumentTypeError(f"no recordings in {text!r}")
    return path


def positive_float(text: str) -> float:
    """A finite number > 0."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not 0 < value < math.inf:
        raise argparse.ArgumentTypeError(f"must be finite and > 0, got {value}")
    return value
