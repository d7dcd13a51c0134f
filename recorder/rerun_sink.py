"""Rerun sink: one `RecordingStream` per run, saved to a .rrd with a default blueprint.

Layout (entity paths = the names in `recorder.schema`):
- properties `run` (metadata) and `outcome`, each key holding JSON text;
- `/world/...` 3D data; mesh triangle indices static, vertex positions per step;
- `/metrics/<name>` and `/state/<field>` Scalars (float64) on timelines `step` and `sim_time`;
- `/reference/safety_margin` per step when a margin is given, `/log` TextLog.
The wall-clock timeline is off and the recording id comes from the caller.

Per-step data is queued and sent as columns (`send_columns`, one call per entity) at each flush:
far less per-step overhead than one `log` call per entity and step. Style that never changes
(radii, colours, series names) is logged once as static.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from datetime import timedelta
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from recorder import schema
from recorder.events import Step

_ROBOT_COLOR = (190, 190, 205)

_LEVELS = {"debug": "DEBUG", "info": "INFO", "warning": "WARN", "warn": "WARN", "error": "ERROR",
           "critical": "CRITICAL"}


def _blueprint(extra_metrics: bool) -> rrb.Blueprint:
    distances = [f"{schema.METRICS}/{name}" for name in schema.DISTANCE_METRICS] + [schema.SAFETY_MARGIN]
    plots = [
        rrb.TimeSeriesView(name="distances [m]", origin="/", contents=distances),
        rrb.TimeSeriesView(name="solver [ms]", origin="/", contents=[f"{schema.METRICS}/solver_ms"]),
    ]
    if extra_metrics:
        plots.append(rrb.TimeSeriesView(name="metrics", origin=schema.METRICS))
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(name="world", origin="/world"),
            rrb.Vertical(*plots, rrb.TextLogView(name="log", origin=schema.LOG)),
        ),
        collapse_panels=True,
    )


def _obstacle_style(archetype):
    """Static style of the obstacle shapes: translucent red with major wireframe."""
    fill = rr.components.FillMode.TransparentFillMajorWireframe
    return archetype.from_fields(colors=[(230, 80, 50, 128)], fill_mode=fill)


def _batcher_config() -> rr.ChunkBatcherConfig:
    """Rerun's batcher without its periodic tick: this sink flushes explicitly.

    rerun-sdk keeps every Python-created recording (and its batcher threads) alive until the
    process ends (rerun-io/rerun#2116); with the default 8 ms tick, thousands of finished runs in
    one process keep waking up and load the CPU. Without the tick they only sleep.
    """
    config = rr.ChunkBatcherConfig.DEFAULT()
    config.flush_tick = timedelta(days=1)
    return config


def _concat(parts: list):
    """Rows of several steps as one batch: one array if they stack, else a list of rows (ragged strips)."""
    if all(isinstance(p, np.ndarray) for p in parts) and len({p.shape[1:] for p in parts}) == 1:
        return np.concatenate(parts)
    return [row for part in parts for row in part]


@dataclass
class _Column:
    """Steps queued for one entity: index values, rows' lengths and component values."""

    archetype: Any
    steps: list[int] = field(default_factory=list)
    times: list[int] = field(default_factory=list)
    lengths: list[int] = field(default_factory=list)
    values: dict[str, list] = field(default_factory=dict)


class RerunSink:
    """Writes one run to `path` (.rrd). `recording_id` should be derived from the run for reproducibility."""

    def __init__(self, path: Path, *, app_id: str, recording_id: str, run_name: str, safety_margin: float | None):
        self._rec = rr.RecordingStream(app_id, recording_id=recording_id, send_properties=False,
                                       batcher_config=_batcher_config())
        self._rec.set_log_time_enabled(False)
        self._rec.save(str(path), default_blueprint=_blueprint(extra_metrics=True))
        self._rec.send_recording_name(run_name)
        self._rec.log("/world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        self._safety_margin = safety_margin
        self._seen: set[str] = set()
        self._pending: dict[str, _Column] = {}

    def log_run(self, meta: Mapping[str, Any]) -> None:
        self._rec.send_property("run", rr.AnyValues(**schema.encode_meta(meta)))

    def _time(self, step: int, sim_time_ns: int) -> None:
        self._rec.set_time(schema.STEP_TIMELINE, sequence=step)
        self._rec.set_time(schema.SIM_TIME_TIMELINE, duration=np.timedelta64(sim_time_ns, "ns"))

    def _queue(self, s: Step, entity: str, archetype, static, **components) -> None:
        """Queue one step's `components` (arrays of equal length n_i) for `_send_queued`.

        `static()` makes what is logged once as static the first time `entity` is seen (triangle
        indices, radii, series names ...): built only then.
        """
        if entity not in self._seen:
            self._rec.log(entity, static(), static=True)
            self._seen.add(entity)
        column = self._pending.setdefault(entity, _Column(archetype))
        column.steps.append(s.step)
        column.times.append(s.sim_time_ns)
        column.lengths.append(len(next(iter(components.values()))))
        for name, value in components.items():
            column.values.setdefault(name, []).append(value)

    def _send_queued(self) -> None:
        """One `send_columns` per entity for all steps queued since the last flush."""
        for entity, c in self._pending.items():
            indexes = [rr.TimeColumn(schema.STEP_TIMELINE, sequence=c.steps),
                       rr.TimeColumn(schema.SIM_TIME_TIMELINE, duration=np.array(c.times, dtype="timedelta64[ns]"))]
            data = {name: _concat(parts) for name, parts in c.values.items()}
            self._rec.send_columns(entity, indexes=indexes, columns=c.archetype.columns(**data).partition(c.lengths))
        self._pending.clear()

    def log_step(self, s: Step) -> None:
        """Queue one step (every entity given, the mesh included: Rerun logs it cheaply)."""
        if s.mesh_vertices is not None:
            topology = lambda: rr.Mesh3D.from_fields(  # noqa: E731
                triangle_indices=s.mesh_triangles, albedo_factor=_ROBOT_COLOR)
            self._queue(s, schema.MESH, rr.Mesh3D, topology, vertex_positions=s.mesh_vertices)
        if s.backbone is not None:
            self._queue(s, schema.BACKBONE, rr.LineStrips3D, lambda: rr.LineStrips3D.from_fields(radii=0.002),
                        strips=s.backbone)
        if s.obstacle_points is not None:
            self._queue(s, schema.OBSTACLE_POINTS, rr.Points3D, lambda: rr.Points3D.from_fields(radii=0.004),
                        positions=s.obstacle_points)
        if s.obstacle_shapes is not None:
            sh = s.obstacle_shapes
            self._queue(s, f"{schema.OBSTACLE_SHAPES}/spheres", rr.Ellipsoids3D,
                        lambda: _obstacle_style(rr.Ellipsoids3D), centers=sh.sphere_centers,
                        half_sizes=np.repeat(sh.sphere_radii[:, None], 3, axis=1))
            self._queue(s, f"{schema.OBSTACLE_SHAPES}/boxes", rr.Boxes3D, lambda: _obstacle_style(rr.Boxes3D),
                        centers=sh.box_centers, half_sizes=sh.box_sizes / 2)
        if s.goal_rotation is not None:  # a pose: its frame, with a point at the origin
            self._time(s.step, s.sim_time_ns)
            self._rec.log(schema.GOAL, rr.Transform3D(translation=s.goal_position, mat3x3=s.goal_rotation),
                          rr.Points3D(np.zeros((1, 3)), radii=0.01))
        elif s.goal_position is not None:
            self._queue(s, schema.GOAL, rr.Points3D, lambda: rr.Points3D.from_fields(radii=0.01),
                        positions=s.goal_position[None])
        if s.plan is not None:
            self._queue(s, schema.PLAN, rr.LineStrips3D, lambda: rr.LineStrips3D.from_fields(radii=0.002),
                        strips=s.plan[None])
        if s.state is not None:
            for field in schema.STATE_FIELDS:
                flat = s.state[field].ravel()
                names = lambda: rr.SeriesLines(names=schema.state_columns(field, flat.size))  # noqa: E731
                self._queue(s, f"{schema.STATE}/{field}", rr.Scalars, names, scalars=flat)
        for name, value in s.metrics.items():
            self._queue(s, f"{schema.METRICS}/{name}", rr.Scalars, lambda: rr.SeriesLines(names=[name]),
                        scalars=np.array([value]))
        if self._safety_margin is not None:
            self._queue(s, schema.SAFETY_MARGIN, rr.Scalars, lambda: rr.SeriesLines(names=["safety margin"]),
                        scalars=np.array([self._safety_margin]))

    def log_text(self, message: str, level: str, step: int, sim_time_ns: int) -> None:
        self._time(step, sim_time_ns)
        self._rec.log(schema.LOG, rr.TextLog(message, level=_LEVELS.get(level.lower(), level.upper())))

    def flush(self) -> None:
        self._send_queued()
        self._rec.flush()

    def close(self, outcome: Mapping[str, Any]) -> None:
        """Write the outcome property, then flush and finalise the file (footer)."""
        self._rec.send_property("outcome", rr.AnyValues(**schema.encode_meta(outcome)))
        self._send_queued()
        self._rec.flush()
        self._rec.disconnect()
