"""The recording contract: topic names, JSON schemas and the encodings both sinks share.

This module is the one source of truth for what a recording contains. The
MCAP topics and the Rerun entity paths are the same strings (see DESIGN.md).
Everything here is pure Python/NumPy: no sink library is imported.
"""

from __future__ import annotations

import json
import math
from typing import Any, Mapping

import numpy as np

# ---------------------------------------------------------------- names
#: The run's metadata: an MCAP metadata record and a Rerun recording property of this name.
RUN = "run"
MESH = "/world/robot/mesh"
BACKBONE = "/world/robot/backbone"
OBSTACLE_POINTS = "/world/obstacles/points"
OBSTACLE_SHAPES = "/world/obstacles/shapes"
#: The world's still meshes (a wall, a cabinet, a user's file), once at the start: one entity per mesh.
OBSTACLE_MESHES = "/world/obstacles/meshes"
GOAL = "/world/goal"
#: The goal region (a sphere of the goal tolerance) and, for a pose goal, its approach axis; in world
#: coordinates. Logged when the recorder knows the goal tolerance.
GOAL_MARKER = "/world/goal_marker"
PLAN = "/world/plan"
STATE = "/state"
METRICS = "/metrics"
OUTCOME = "/outcome"
LOG = "/log"
#: Rerun only: the safety margin, logged per step so it draws as a line beside the distances.
SAFETY_MARGIN = "/reference/safety_margin"
#: Rerun only: the goal tolerance, logged per step so it draws as a line beside the goal distance.
GOAL_TOLERANCE = "/reference/goal_tolerance"

#: Rerun timelines (MCAP messages carry both inside their JSON body).
STEP_TIMELINE = "step"
SIM_TIME_TIMELINE = "sim_time"

#: The metrics every closed-loop step reports, in column order. Extra float keys follow, sorted.
STANDARD_METRICS = ("goal_distance", "predicted_min_distance", "true_min_distance", "solver_ms")
#: Metrics drawn in the "clearance" plot of the Rerun blueprint (tenths of a metre: the goal distance,
#: metres, has a plot of its own).
CLEARANCE_METRICS = ("predicted_min_distance", "true_min_distance", "current_min_distance")

OUTCOMES = ("success", "collision", "stuck", "interrupted")
#: The ``scenario`` of an experiment folder's manifest (``scenarios.manifest``): a recording of what
#: produced the runs beside it, not an episode; ``recorder.read`` lists manifests apart.
MANIFEST = "experiment"
#: Outcome fields in order; all but `outcome` may be None.
OUTCOME_FIELDS = ("outcome", "steps", "reach_step", "min_true_distance", "first_collision_step")

#: State arrays: name -> (Rerun entity under /state, DataFrame column names for M links).
STATE_FIELDS = ("arc_lengths", "theta", "phi", "ee_position")

#: Columns `load_runs` adds to the per-run table; run metadata must not use these keys.
RUN_TABLE_COLUMNS = ("run_id", "path", "format", "complete") + OUTCOME_FIELDS

# ---------------------------------------------------------------- JSON schemas (MCAP)
_NUMBER_OR_NULL = {"type": ["number", "null"]}
_INT_OR_NULL = {"type": ["integer", "null"]}
_VECTOR = {"type": "array", "items": {"type": "number"}}

METRICS_SCHEMA = {
    "title": "ncedf.Metrics",
    "description": "Per-step scalars. NaN is written as null. Distances in metres, solver time in ms.",
    "type": "object",
    "properties": {
        "step": {"type": "integer"},
        "sim_time": {"type": "number", "description": "seconds"},
        **{name: _NUMBER_OR_NULL for name in STANDARD_METRICS},
    },
    "additionalProperties": _NUMBER_OR_NULL,
    "required": ["step", "sim_time"],
}

STATE_SCHEMA = {
    "title": "ncedf.State",
    "description": "Robot state of M links: arc lengths (M x 3, m), theta and phi (M, rad), end effector (3, m).",
    "type": "object",
    "properties": {
        "step": {"type": "integer"},
        "sim_time": {"type": "number", "description": "seconds"},
        "arc_lengths": {"type": "array", "items": _VECTOR},
        "theta": _VECTOR,
        "phi": _VECTOR,
        "ee_position": _VECTOR,
    },
    "required": ["step", "sim_time", *STATE_FIELDS],
}

OUTCOME_SCHEMA = {
    "title": "ncedf.Outcome",
    "type": "object",
    "properties": {
        "outcome": {"type": "string", "enum": list(OUTCOMES)},
        "steps": _INT_OR_NULL,
        "reach_step": _INT_OR_NULL,
        "min_true_distance": _NUMBER_OR_NULL,
        "first_collision_step": _INT_OR_NULL,
    },
    "required": list(OUTCOME_FIELDS),
}


# ---------------------------------------------------------------- encodings
def sim_time_ns(sim_time: float) -> int:
    """Seconds -> integer nanoseconds, the resolution both formats store `sim_time` at."""
    return int(round(float(sim_time) * 1e9))


def json_float(x: float) -> float | None:
    """A float as JSON stores it: NaN and infinities become null (read back as NaN)."""
    x = float(x)
    return x if math.isfinite(x) else None


def encode_meta(meta: Mapping[str, Any]) -> dict[str, str]:
    """Run metadata -> {key: JSON text}, the form both MCAP metadata and Rerun properties store.

    Values must be JSON-serialisable (numbers, strings, bools, None, lists, dicts).
    """
    out = {}
    for key, value in meta.items():
        try:
            out[str(key)] = json.dumps(value, sort_keys=True, allow_nan=False)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"run metadata {key!r} is not JSON-serialisable: {exc}") from None
    return out


def decode_meta(encoded: Mapping[str, str]) -> dict[str, Any]:
    """Inverse of `encode_meta`."""
    return {key: json.loads(text) for key, text in encoded.items()}


def metric_columns(names) -> list[str]:
    """Column order of a metrics table: step, sim_time, the standard metrics, then extras sorted."""
    names = set(names) - {"step", "sim_time"}
    standard = [n for n in STANDARD_METRICS if n in names]
    return ["step", "sim_time", *standard, *sorted(names - set(standard))]


def state_columns(field: str, size: int) -> list[str]:
    """Flattened DataFrame column names of one state field.

    arc_lengths (M x 3) -> arc_1_1 .. arc_M_3 (link i, chamber j, 1-based);
    theta, phi (M,) -> theta_1 .. theta_M; ee_position (3,) -> ee_x, ee_y, ee_z.
    """
    if field == "arc_lengths":
        return [f"arc_{i // 3 + 1}_{i % 3 + 1}" for i in range(size)]
    if field == "ee_position":
        return ["ee_x", "ee_y", "ee_z"][:size]
    return [f"{field}_{i + 1}" for i in range(size)]


def state_table_columns(links: int) -> list[str]:
    """All columns of a state table for `links` links, in order (after step and sim_time)."""
    sizes = {"arc_lengths": 3 * links, "theta": links, "phi": links, "ee_position": 3}
    return [c for f in STATE_FIELDS for c in state_columns(f, sizes[f])]


def flatten_state(values: Mapping[str, Any]) -> dict[str, float]:
    """{field: array} -> {column: float} using `state_columns` (the layout of the state table)."""
    row = {}
    for field in STATE_FIELDS:
        flat = np.asarray(values[field], dtype=np.float64).ravel()
        row.update(zip(state_columns(field, flat.size), flat.tolist()))
    return row


def normalise_outcome(outcome: Mapping[str, Any]) -> dict[str, Any]:
    """Check an outcome dict and return it with every field of `OUTCOME_FIELDS` (missing -> None)."""
    if outcome.get("outcome") not in OUTCOMES:
        raise ValueError(f"outcome must be one of {OUTCOMES}, got {outcome.get('outcome')!r}")
    unknown = set(outcome) - set(OUTCOME_FIELDS)
    if unknown:
        raise ValueError(f"unknown outcome fields {sorted(unknown)}; allowed: {OUTCOME_FIELDS}")
    out: dict[str, Any] = {"outcome": outcome["outcome"]}
    for key in OUTCOME_FIELDS[1:]:
        value = outcome.get(key)
        if value is None:
            out[key] = None
        elif key == "min_true_distance":
            out[key] = json_float(value)
        else:
            out[key] = int(value)
    return out
