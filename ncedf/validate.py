"""Validation of the controller's small frozen configs: one line naming the field and the bad value."""

from __future__ import annotations

import dataclasses
import math

import numpy as np


def _number(config, name: str) -> float:
    value = getattr(config, name)
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValueError(f"{type(config).__name__}.{name} must be a number, got {value!r}")
    if not math.isfinite(value):
        raise ValueError(f"{type(config).__name__}.{name} must be finite, got {value!r}")
    return float(value)


def _fail(config, name: str, rule: str):
    raise ValueError(f"{type(config).__name__}.{name} must be {rule}, got {getattr(config, name)!r}")


def unknown_fields(kind: type, data: dict) -> list[str]:
    """The keys of ``data`` that are not fields of the dataclass ``kind``, sorted."""
    return sorted(set(data) - {field.name for field in dataclasses.fields(kind)})


def nested(config, name: str, kind: type) -> None:
    """Make ``config``'s field ``name`` a ``kind``, built from its fields where it is a dict (a
    recording's settings); raise ValueError naming the field where it is neither or a key is unknown."""
    value = getattr(config, name)
    if isinstance(value, dict):
        unknown = unknown_fields(kind, value)
        if unknown:
            _fail(config, name, f"a {kind.__name__} (no field {', '.join(unknown)})")
        object.__setattr__(config, name, kind(**value))
    elif not isinstance(value, kind):
        raise ValueError(f"{type(config).__name__}.{name} must be a {kind.__name__}, got {type(value).__name__}")


def check_fields(config, *, integers=(), counts=(), positive=(), non_negative=(), fractions=(), unit=None,
                 positive_or_none=(), flags=(), choices=None) -> None:
    """Raise ValueError naming the first bad field of ``config``.

    integers: ints >= 1.  counts: ints >= 0.  positive: numbers > 0.  non_negative: numbers >= 0.
    fractions: numbers in (0, 1].  unit: {name: (lo, hi)} numbers in [lo, hi).
    positive_or_none: as positive, or None.  flags: bools.
    choices: {name: allowed values}.
    """
    for name in integers + counts:
        value = getattr(config, name)
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
            _fail(config, name, "an integer")
        if value < (1 if name in integers else 0):
            _fail(config, name, ">= 1" if name in integers else ">= 0")
    for name in positive + tuple(n for n in positive_or_none if getattr(config, n) is not None):
        if _number(config, name) <= 0:
            _fail(config, name, "> 0" + (" or None" if name in positive_or_none else ""))
    for name in non_negative:
        if _number(config, name) < 0:
            _fail(config, name, ">= 0")
    for name in fractions:
        if not 0 < _number(config, name) <= 1:
            _fail(config, name, "in (0, 1]")
    for name, (lo, hi) in (unit or {}).items():
        if not lo <= _number(config, name) < hi:
            _fail(config, name, f"in [{lo:g}, {hi:g})")
    for name in flags:
        if not isinstance(getattr(config, name), bool):
            _fail(config, name, "a bool")
    for name, allowed in (choices or {}).items():
        if getattr(config, name) not in allowed:
            _fail(config, name, "one of " + ", ".join(map(str, allowed)))
