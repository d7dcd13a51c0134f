"""Rerun sink: one `RecordingStream` per run, saved to a .rrd with a default blueprint.

Layout (entity paths = the names in `recorder.schema`):
- properties `run` (metadata) and `outcome`, each key holding JSON text;
- `/world/...` 3D data; mesh triangle indices static, vertex positions per step;
- `/metrics/<name>` and `/state/<field>` Scalars (float64) on timelines `step` and `sim_time`,
  buffered and sent as columns at each flush (one call per entity instead of one per step);
- `/reference/safety_margin` per step when a margin is given, `/log` TextLog.
The wall-clock timeline is off and the recording id comes from the caller.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from recorder import schema
from recorder.events import Step

_LEVELS = {"debug": "DEBUG", "info": "INFO", "warning": "WARN", "warn": "WARN", "error": "ERROR", "critical": "CRITICAL"}


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


class RerunSink:
    """Writes one run to `path` (.rrd). `recording_id` should be derived from the run for reproducibility."""

    def __init__(self, path: Path, *, app_id: str, recording_id: str, run_name: str, safety_margin: float | None):
        self._rec = rr.RecordingStream(app_id, recording_id=recording_id, send_properties=False)
        self._rec.set_log_time_enabled(False)
        self._rec.save(str(path), default_blueprint=_blueprint(extra_metrics=True))
        self._rec.send_recording_name(run_name)
        self._rec.log("/world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        self._safety_margin = safety_margin
        self._styled: set[str] = set()
        self._pending: dict[str, tuple[list[int], list[int], list[np.ndarray]]] = {}

    def log_run(self, meta: Mapping[str, Any]) -> None:
        self._rec.send_property("run", rr.AnyValues(**schema.encode_meta(meta)))

    def _time(self, step: int, sim_time_ns: int) -> None:
        self._rec.set_time(schema.STEP_TIMELINE, sequence=step)
        self._rec.set_time(schema.SIM_TIME_TIMELINE, duration=np.timedelta64(sim_time_ns, "ns"))

    def _series(self, s: Step, entity: str, values: np.ndarray, names: list[str]) -> None:
        """Queue float64 scalars of one step (sent by `_send_scalars`); name the series once (static style)."""
        if entity not in self._styled:
            self._rec.log(entity, rr.SeriesLines(names=names), static=True)
            self._styled.add(entity)
        steps, times, rows = self._pending.setdefault(entity, ([], [], []))
        steps.append(s.step)
        times.append(s.sim_time_ns)
        rows.append(values)

    def _send_scalars(self) -> None:
        for entity, (steps, times, rows) in self._pending.items():
            indexes = [rr.TimeColumn(schema.STEP_TIMELINE, sequence=steps),
                       rr.TimeColumn(schema.SIM_TIME_TIMELINE, duration=np.array(times, dtype="timedelta64[ns]"))]
            self._rec.send_columns(entity, indexes=indexes, columns=rr.Scalars.columns(scalars=np.stack(rows)))
        self._pending.clear()

    def log_step(self, s: Step, *, log_mesh: bool, first_mesh: bool) -> None:
        rec = self._rec
        self._time(s.step, s.sim_time_ns)
        if log_mesh and s.mesh_vertices is not None:
            if first_mesh and s.mesh_triangles is not None:
                rec.log(schema.MESH, rr.Mesh3D.from_fields(triangle_indices=s.mesh_triangles), static=True)
            rec.log(schema.MESH, rr.Mesh3D.from_fields(vertex_positions=s.mesh_vertices))
        if s.backbone is not None:
            rec.log(schema.BACKBONE, rr.LineStrips3D(s.backbone, radii=0.002))
        if s.obstacle_points is not None:
            rec.log(schema.OBSTACLE_POINTS, rr.Points3D(s.obstacle_points, radii=0.004))
        if s.obstacle_shapes is not None:
            sh = s.obstacle_shapes
            rec.log(f"{schema.OBSTACLE_SHAPES}/spheres", rr.Ellipsoids3D(centers=sh.sphere_centers, radii=sh.sphere_radii))
            rec.log(f"{schema.OBSTACLE_SHAPES}/boxes", rr.Boxes3D(centers=sh.box_centers, sizes=sh.box_sizes))
        if s.goal_rotation is not None:  # a pose: its frame, with a point at the origin
            rec.log(schema.GOAL, rr.Transform3D(translation=s.goal_position, mat3x3=s.goal_rotation),
                    rr.Points3D(np.zeros((1, 3)), radii=0.01))
        elif s.goal_position is not None:
            rec.log(schema.GOAL, rr.Points3D(s.goal_position[None], radii=0.01))
        if s.plan is not None:
            rec.log(schema.PLAN, rr.LineStrips3D(s.plan[None], radii=0.002))
        if s.state is not None:
            for field in schema.STATE_FIELDS:
                flat = s.state[field].ravel()
                self._series(s, f"{schema.STATE}/{field}", flat, schema.state_columns(field, flat.size))
        for name, value in s.metrics.items():
            self._series(s, f"{schema.METRICS}/{name}", np.array([value]), [name])
        if self._safety_margin is not None:
            self._series(s, schema.SAFETY_MARGIN, np.array([self._safety_margin]), ["safety margin"])

    def log_text(self, message: str, level: str, step: int, sim_time_ns: int) -> None:
        self._time(step, sim_time_ns)
        self._rec.log(schema.LOG, rr.TextLog(message, level=_LEVELS.get(level.lower(), level.upper())))

    def flush(self) -> None:
        self._send_scalars()
        self._rec.flush()

    def close(self, outcome: Mapping[str, Any]) -> None:
        """Write the outcome property, then flush and finalise the file (footer)."""
        self._rec.send_property("outcome", rr.AnyValues(**schema.encode_meta(outcome)))
        self._send_scalars()
        self._rec.flush()
        self._rec.disconnect()
