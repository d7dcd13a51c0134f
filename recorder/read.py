"""Read recordings (.rrd or .mcap) back into pandas: the only way analysis touches files.

`load_run(path)` gives one `Run`; `load_snapshots(path, times)` the recorded geometry (robot,
cloud, obstacles, goal, plan) of chosen steps of an .mcap (``recorder.scene_read``);
`load_runs(folder)` gives a per-run table and a long per-step metrics table over every recording
under a folder (reading the .mcap of a run when both files exist: it only parses the small JSON
topics). `load_summaries(folder)` gives the per-run table with
per-metric statistics, from the `summary` record of closed .mcap files (footer and summary section
only: no chunk is opened) and from the rows of every other recording.

Both formats of one run give equal tables: every scalar is float64 in both (Rerun Scalars,
JSON numbers), `sim_time` is stored to 1 ns in both (Rerun duration timeline, rounded
seconds in JSON), NaN round-trips (as null in JSON).
"""

from __future__ import annotations

import json
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from recorder import mcap_scan, schema, summary
from recorder.errors import RecorderError
from recorder.scene_read import Snapshot, snapshots as load_snapshots

__all__ = ["IncompleteRecordingWarning", "Run", "Snapshot", "find_recordings", "load_run", "load_runs",
           "load_snapshots", "load_summaries"]

_RRD_MAGIC = b"RRF2"
_RRD_FOOTER_TAIL = b"RRF2FOOT"


class IncompleteRecordingWarning(UserWarning):
    """The file was not closed (run killed): what was flushed is read, the tail may be missing."""


@dataclass(frozen=True)
class Run:
    """One recording read back.

    meta: run metadata; metrics: one row per step (step, sim_time [s], then the metric columns,
    see `schema.metric_columns`); state: one row per step (step, sim_time, arc_i_j, theta_i, phi_i,
    ee_x, ee_y, ee_z, see `schema.state_columns`); outcome: dict of `schema.OUTCOME_FIELDS` or None
    when the run never finished; complete: the file was closed properly.
    """

    path: Path
    format: str
    meta: dict[str, Any]
    metrics: pd.DataFrame
    state: pd.DataFrame
    outcome: dict[str, Any] | None
    complete: bool


@dataclass
class _Raw:
    """What a format reader extracts: rows keyed by nothing but their own `step` field."""

    meta: dict[str, Any] = field(default_factory=dict)
    metrics: list[dict[str, Any]] = field(default_factory=list)
    state: list[dict[str, Any]] = field(default_factory=list)
    outcome: dict[str, Any] | None = None
    complete: bool = False


# ---------------------------------------------------------------- MCAP
def _read_mcap(path: Path, with_state: bool) -> _Raw:
    """Metadata and the JSON topics (works on unclosed files: reads up to the last whole chunk)."""
    topics = (schema.METRICS, schema.OUTCOME, schema.STATE) if with_state else (schema.METRICS, schema.OUTCOME)
    try:
        found = mcap_scan.scan(path, topics)
    except mcap_scan.NotMcap:
        raise RecorderError(f"{path} is not an MCAP recording") from None
    except Exception as exc:  # corrupt content: struct, decoding or decompression errors
        raise RecorderError(f"{path} is not a readable MCAP recording: {exc}") from None
    raw = _Raw(meta=schema.decode_meta(found.metadata.get(schema.RUN, {})), complete=found.footer)
    raw.metrics = [json.loads(data) for _, data in found.messages[schema.METRICS]]
    for row in raw.metrics:
        for key, value in row.items():
            if value is None:
                row[key] = np.nan
    for _, data in found.messages.get(schema.STATE, []):
        msg = json.loads(data)
        raw.state.append({"step": msg["step"], "sim_time": msg["sim_time"], **schema.flatten_state(msg)})
    if found.messages[schema.OUTCOME]:
        raw.outcome = json.loads(found.messages[schema.OUTCOME][-1][1])
    return raw


# ---------------------------------------------------------------- RRD
def _property(batch) -> dict[str, Any]:
    return schema.decode_meta({name: batch.column(name)[0][0].as_py() for name in batch.schema.names
                               if name != "rerun.controls.RowId"})


def _read_rrd(path: Path, with_state: bool) -> _Raw:
    """Read the `/metrics/*`, `/state/*` scalars and the `run`/`outcome` properties."""
    import pyarrow as pa
    import rerun.chunk as rc

    with open(path, "rb") as f:
        head = f.read(4)
        f.seek(max(0, path.stat().st_size - 16))
        tail = f.read()
    if head != _RRD_MAGIC:
        raise RecorderError(f"{path} is not a Rerun recording (.rrd)")
    raw = _Raw(complete=_RRD_FOOTER_TAIL in tail)
    try:
        with warnings.catch_warnings():  # rerun warns about a missing footer; `complete` reports it
            warnings.simplefilter("ignore")
            reader = rc.RrdReader(path)
        contents = [f"{schema.METRICS}/**", "/__properties/**"] + ([f"{schema.STATE}/**"] if with_state else [])
        chunks = reader.stream().filter(content=contents).to_chunks()
    except Exception as exc:
        raise RecorderError(f"{path} is not a readable Rerun recording: {exc}") from None

    metrics: dict[int, dict[str, Any]] = {}
    state: dict[int, dict[str, Any]] = {}
    for chunk in chunks:
        entity = chunk.entity_path
        batch = chunk.to_record_batch()
        if entity == "/__properties/run":
            raw.meta = _property(batch)
            continue
        if entity == "/__properties/outcome":
            raw.outcome = _property(batch)
            continue
        if chunk.is_static or "Scalars:scalars" not in batch.schema.names:
            continue
        parent, name = entity.rsplit("/", 1)
        steps = batch.column(schema.STEP_TIMELINE).to_numpy()
        times = batch.column(schema.SIM_TIME_TIMELINE).cast(pa.int64()).to_numpy() / 1e9
        scalars = batch.column("Scalars:scalars")
        values = scalars.values.to_numpy(zero_copy_only=False).reshape(len(batch), -1)
        if parent == schema.METRICS:
            target, columns = metrics, [name]
        elif parent == schema.STATE:
            target, columns = state, schema.state_columns(name, values.shape[1])
        else:
            continue
        for step, t, row in zip(steps.tolist(), times.tolist(), values.tolist()):
            entry = target.setdefault(step, {"step": step, "sim_time": t})
            entry.update(zip(columns, row))
    raw.metrics = [metrics[k] for k in sorted(metrics)]
    raw.state = [state[k] for k in sorted(state)]
    return raw


# ---------------------------------------------------------------- tables
def _metrics_frame(rows: list[dict[str, Any]]) -> pd.DataFrame:
    names = set().union(*rows) if rows else {"step", "sim_time"}
    df = pd.DataFrame.from_records(rows, columns=schema.metric_columns(names))
    return _typed(df)


def _state_frame(rows: list[dict[str, Any]]) -> pd.DataFrame:
    links = sum(1 for c in rows[0] if c.startswith("theta_")) if rows else 0
    columns = ["step", "sim_time", *schema.state_table_columns(links)] if rows else ["step", "sim_time"]
    return _typed(pd.DataFrame.from_records(rows, columns=columns))


def _typed(df: pd.DataFrame) -> pd.DataFrame:
    """step int64, everything else float64, ordered by step, index 0..n-1."""
    df = df.astype({c: "int64" if c == "step" else "float64" for c in df.columns})
    return df.sort_values("step", kind="stable").reset_index(drop=True)


def _read_raw(path: Path, with_state: bool = True) -> tuple[str, _Raw]:
    path = Path(path)
    if not path.is_file():
        raise RecorderError(f"{path} does not exist or is not a file")
    if path.suffix == ".mcap":
        fmt, raw = "mcap", _read_mcap(path, with_state)
    elif path.suffix == ".rrd":
        fmt, raw = "rrd", _read_rrd(path, with_state)
    else:
        raise RecorderError(f"{path}: expected a .rrd or .mcap recording")
    if raw.outcome is not None:
        raw.outcome = {k: raw.outcome.get(k) for k in schema.OUTCOME_FIELDS}
    if not raw.complete:
        warnings.warn(f"{path} was not closed (run killed?): read {len(raw.metrics)} steps that were flushed",
                      IncompleteRecordingWarning, stacklevel=3)
    return fmt, raw


def load_run(path: str | Path) -> Run:
    """Read one .rrd or .mcap recording. Raises `RecorderError` for a missing or unreadable file;
    warns `IncompleteRecordingWarning` for a file that was not closed (it reads what is there)."""
    fmt, raw = _read_raw(Path(path))
    return Run(path=Path(path), format=fmt, meta=raw.meta, metrics=_metrics_frame(raw.metrics),
               state=_state_frame(raw.state), outcome=raw.outcome, complete=raw.complete)


def find_recordings(folder: str | Path) -> list[Path]:
    """Every recording under `folder` (recursively), one file per run: the .mcap if a run has both."""
    folder = Path(folder)
    if not folder.is_dir():
        raise RecorderError(f"{folder} is not a folder")
    chosen: dict[Path, Path] = {}
    for path in sorted(folder.rglob("*.rrd")) + sorted(folder.rglob("*.mcap")):
        chosen[path.with_suffix("")] = path  # .mcap files come last and win
    return [chosen[k] for k in sorted(chosen)]


def _run_row(path: Path, fmt: str, meta: dict[str, Any], outcome: dict[str, Any] | None,
             complete: bool) -> dict[str, Any]:
    """One row of the per-run table (nested metadata still nested)."""
    outcome = outcome or {k: None for k in schema.OUTCOME_FIELDS}
    return {"run_id": str(meta.get("run_id", path.stem)), "path": str(path), "format": fmt, "complete": complete,
            **{k: outcome.get(k) for k in schema.OUTCOME_FIELDS}, **{k: v for k, v in meta.items() if k != "run_id"}}


def _runs_frame(rows: list[dict[str, Any]]) -> pd.DataFrame:
    return pd.json_normalize(rows) if rows else pd.DataFrame(columns=list(schema.RUN_TABLE_COLUMNS))


def _read_quietly(path: Path) -> tuple[str, _Raw] | None:
    """`_read_raw` without state and without the unclosed-file warning; None (and a warning naming the
    file) when it cannot be read."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", IncompleteRecordingWarning)
            return _read_raw(path, with_state=False)
    except RecorderError as exc:
        warnings.warn(f"skipped: {exc}", stacklevel=3)
        return None


#: What :func:`load_runs` and :func:`load_summaries` list: the episodes, the manifests or both.
KINDS = ("episodes", "manifests", "all")


def _check_kind(kind: str) -> None:
    if kind not in KINDS:
        raise ValueError(f"kind must be one of {', '.join(KINDS)}, got {kind!r}")


def _wanted(meta: dict[str, Any], kind: str) -> bool:
    """Whether a recording with run metadata ``meta`` is of ``kind`` (:data:`KINDS`)."""
    return kind == "all" or (meta.get("scenario") == schema.MANIFEST) == (kind == "manifests")


def load_runs(folder: str | Path, kind: str = "episodes") -> tuple[pd.DataFrame, pd.DataFrame]:
    """All runs under `folder` -> (runs, steps).

    kind: "episodes" (the default: an experiment's manifest, ``schema.MANIFEST``, is not an episode),
    "manifests" or "all".

    runs: one row per run: run_id, path, format, complete, the outcome fields, then the run
    metadata (nested dicts flattened to dotted names, e.g. `mppi.horizon`).
    steps: the long per-step metrics table, `run_id` first, then the metrics columns.
    Unreadable files are skipped with a warning naming them.
    """
    _check_kind(kind)
    run_rows, step_rows = [], []
    for path in find_recordings(folder):
        read = _read_quietly(path)
        if read is None:
            continue
        fmt, raw = read
        if not _wanted(raw.meta, kind):
            continue
        row = _run_row(path, fmt, raw.meta, raw.outcome, raw.complete)
        run_rows.append(row)
        for metrics in raw.metrics:
            metrics["run_id"] = row["run_id"]
        step_rows.extend(raw.metrics)
    names = set().union(*step_rows) - {"run_id"} if step_rows else set()
    steps = pd.DataFrame.from_records(step_rows, columns=["run_id", *schema.metric_columns(names)])
    steps = steps.astype({c: "int64" if c == "step" else "float64" for c in steps.columns if c != "run_id"})
    return _runs_frame(run_rows), steps


def _summary_record(path: Path) -> dict[str, Any] | None:
    """The per-run row from a closed .mcap's `run` and `summary` records; None when it has none."""
    try:
        records = mcap_scan.indexed_metadata(path)
    except Exception:  # not an MCAP or a corrupt tail: the full read decides (and names the problem)
        return None
    if not records or summary.RECORD not in records:
        return None
    outcome, stats = summary.decode(records[summary.RECORD])
    return {**_run_row(path, "mcap", schema.decode_meta(records.get(schema.RUN, {})), outcome, True),
            **summary.columns(stats)}


def load_summaries(folder: str | Path, kind: str = "episodes") -> pd.DataFrame:
    """All runs under `folder` (of `kind`, as `load_runs`) -> one row per run: the columns of
    `load_runs`' runs table, then
    `summary.ROWS` (the number of /metrics rows) and, per metric column, `<metric>.<stat>` for each of
    `summary.STATS` (count of finite values, mean, population std, min, max, last finite value and its step).

    A closed .mcap written with the `summary` record is read from its footer and summary section only;
    .rrd files, unclosed files and older recordings are read in full and the same statistics computed
    from their rows (equal values either way). Unreadable files are skipped with a warning naming them.
    """
    _check_kind(kind)
    rows = []
    for path in find_recordings(folder):
        row = _summary_record(path) if path.suffix == ".mcap" else None
        if row is None:
            read = _read_quietly(path)
            if read is None:
                continue
            fmt, raw = read
            row = {**_run_row(path, fmt, raw.meta, raw.outcome, raw.complete),
                   **summary.columns(summary.summarize(raw.metrics))}
        if _wanted(row, kind):
            rows.append(row)
    return _runs_frame(rows)
