"""Per-run statistics of the /metrics columns: what the MCAP `summary` metadata record holds.

The MCAP sink computes them from the rows it wrote when a run closes; `recorder.read.load_summaries`
reads them from the file's summary section (no chunk is opened) or, for .rrd files, unclosed files
and files written before the record existed, computes them with the same function from the rows read
back. JSON numbers round-trip float64 exactly, so both paths give equal values.
"""

from __future__ import annotations

import math
from typing import Any, Iterable, Mapping

import numpy as np

from recorder import schema

#: Name of the MCAP metadata record.
RECORD = "summary"
#: Statistics per metric column, in order: count of finite values, their mean, population standard
#: deviation (ddof 0), min and max, and the last finite value with its step. All but count are None
#: (NaN once read) when no value is finite.
STATS = ("count", "mean", "std", "min", "max", "last", "last_step")
#: Column of the summary table with the number of /metrics rows (steps recorded).
ROWS = "metric_rows"


def column_stats(steps: np.ndarray, values: np.ndarray) -> dict[str, Any]:
    """`STATS` of one metric column: steps (N,) int, values (N,) float (NaN: missing) in recording order."""
    finite = np.isfinite(values)
    v = values[finite]
    if not v.size:
        return {"count": 0, **{k: None for k in STATS[1:]}}
    return {"count": int(v.size), "mean": float(v.mean()), "std": float(v.std()), "min": float(v.min()),
            "max": float(v.max()), "last": float(v[-1]), "last_step": int(steps[finite][-1])}


def summarize(rows: Iterable[Mapping[str, Any]]) -> dict[str, Any]:
    """/metrics rows (dicts with `step`, `sim_time` and metric values; a missing key or None counts as NaN)
    -> {ROWS: number of rows, "metrics": {column: `column_stats`}}, columns in `schema.metric_columns` order."""
    rows = list(rows)
    names = schema.metric_columns(set().union(*rows) if rows else ())[2:]
    steps = np.array([int(r["step"]) for r in rows], dtype=np.int64)
    out = {}
    for name in names:
        values = np.array([math.nan if r.get(name) is None else float(r[name]) for r in rows], dtype=np.float64)
        out[name] = column_stats(steps, values)
    return {ROWS: len(rows), "metrics": out}


def encode(outcome: Mapping[str, Any], rows: Iterable[Mapping[str, Any]]) -> dict[str, str]:
    """The `summary` metadata record of a closed run: {outcome field: JSON, ROWS: JSON, "metrics": JSON}."""
    return schema.encode_meta({**dict(outcome), **summarize(rows)})


def decode(record: Mapping[str, str]) -> tuple[dict[str, Any], dict[str, Any]]:
    """Inverse of `encode`: (outcome, `summarize`'s dict)."""
    values = schema.decode_meta(record)
    return {k: values.get(k) for k in schema.OUTCOME_FIELDS}, {ROWS: values[ROWS], "metrics": values["metrics"]}


def columns(summary: Mapping[str, Any]) -> dict[str, Any]:
    """`summarize`'s dict -> flat columns {ROWS: n, "<metric>.<stat>": value} (metrics in
    `schema.metric_columns` order, statistics in `STATS` order), None as NaN."""
    out: dict[str, Any] = {ROWS: int(summary[ROWS])}
    metrics = summary["metrics"]
    for name in schema.metric_columns(metrics)[2:]:
        out.update({f"{name}.{k}": math.nan if metrics[name][k] is None else metrics[name][k] for k in STATS})
    return out
