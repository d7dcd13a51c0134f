"""Command-line argument types the benches share (``closed_loop.py``, ``paper_timing.py``),
imported from their folder. They raise ``argparse.ArgumentTypeError``, which the parser
reports in one line naming the option."""

from __future__ import annotations

import argparse


def parse_list(text: str, cast, name: str, allowed=None) -> list:
    """The comma-separated values of ``text``, each ``cast``; non-empty, and each in ``allowed`` if given."""
    try:
        values = [cast(v) for v in text.split(",") if v]
    except ValueError:
        raise argparse.ArgumentTypeError(f"bad {name} list {text!r}") from None
    if not values:
        raise argparse.ArgumentTypeError(f"empty {name} list")
    bad = [v for v in values if allowed is not None and v not in allowed]
    if bad:
        raise argparse.ArgumentTypeError(f"unknown {name} {bad[0]!r}; choose from {', '.join(map(str, allowed))}")
    return values


def positive(text: str) -> int:
    """An integer >= 1."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {value}")
    return value
