"""Rerun sink: one `RecordingStream` per run, saved to a .rrd with a default blueprint, and
optionally a second one streaming the same data live to a viewer (`recorder.viewer`).

Layout (entity paths = the names in `recorder.schema`):
- properties `run` (metadata) and `outcome`, each key holding JSON text;
- `/world/...` 3D data; the world's still meshes static (`/world/obstacles/meshes/<i>`, translucent);
  the robot mesh's triangle indices static, vertex positions (and, with link clearances,
  vertex colours) per step; the plan as a line strip with points at its knots; with a goal
  tolerance, `/world/goal_marker/region` (a translucent sphere) and, for pose goals,
  `/world/goal_marker/approach` (an arrow along the goal's z axis, ending at the goal);
- `/metrics/<name>` and `/state/<field>` Scalars (float64) on timelines `step` and `sim_time`;
- `/reference/safety_margin` and `/reference/goal_tolerance` per step when given, `/log` TextLog.
The blueprint holds a view for each kind of data the steps log (`_lay_out`).
Colours and sizes come from `recorder.style`. The wall-clock timeline is off and the recording id
comes from the caller.

Per-step data is queued and sent as columns (`send_columns`, one call per entity) at each flush:
far less per-step overhead than one `log` call per entity and step. Style that never changes
(radii, colours, series names) is logged once as static. The live stream gets the same calls, its
columns sent after every step so the viewer follows the run; its failures only end the live view.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from datetime import timedelta
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import rerun as rr
import rerun.blueprint as rrb

from recorder import schema, style, viewer
from recorder.events import Step

#: Seconds the live stream may take at the end of a run to hand its tail to the viewer.
_LIVE_CLOSE_TIMEOUT_S = 2.0
_REGION = f"{schema.GOAL_MARKER}/region"
_APPROACH = f"{schema.GOAL_MARKER}/approach"

_LEVELS = {"debug": "DEBUG", "info": "INFO", "warning": "WARN", "warn": "WARN", "error": "ERROR",
           "critical": "CRITICAL"}


#: The metric plots: title -> (the metrics it draws, the reference lines drawn with them).
_PLOTS = {
    "goal distance [m]": (("goal_distance",), (schema.GOAL_TOLERANCE,)),
    "clearance [m]": (schema.CLEARANCE_METRICS, (schema.SAFETY_MARGIN,)),
    "solver [ms]": (("solver_ms",), ()),
}
#: The plot of every metric that no plot of `_PLOTS` draws.
_OTHERS = "other metrics"
_CLAIMED = frozenset(name for names, _ in _PLOTS.values() for name in names)
#: The layout stored when a run starts: a closed-loop run's (the 3D view and the plots of its standard metrics).
_START = (frozenset(_PLOTS), True)


def _plot_titles(metrics) -> frozenset[str]:
    """The titles of the plots that have something to draw among these metric names."""
    names = set(metrics)
    titles = {title for title, (drawn, _) in _PLOTS.items() if names & set(drawn)}
    return frozenset(titles | ({_OTHERS} if names - _CLAIMED else set()))


def _blueprint(titles: frozenset[str], world: bool) -> rrb.Blueprint:
    """The layout of a run: the 3D view of `/world` (if `world`), the plots named in `titles`, the log."""
    plots = [rrb.TimeSeriesView(name=title, origin="/",
                                contents=[f"{schema.METRICS}/{name}" for name in drawn] + list(references))
             for title, (drawn, references) in _PLOTS.items() if title in titles]
    if _OTHERS in titles:
        others = [f"+ {schema.METRICS}/**"] + [f"- {schema.METRICS}/{name}" for name in sorted(_CLAIMED)]
        plots.append(rrb.TimeSeriesView(name=_OTHERS, origin="/", contents=others))
    side = rrb.Vertical(*plots, rrb.TextLogView(name="log", origin=schema.LOG))
    if not world:
        return rrb.Blueprint(side, collapse_panels=True)
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(name="world", origin="/world", background=getattr(rrb.BackgroundKind, style.BACKGROUND)),
            side,
            column_shares=[2, 1],  # room for the default camera to frame the whole scene
        ),
        collapse_panels=True,
    )


def _has_world(s: Step) -> bool:
    """Whether step `s` draws anything in the 3D view."""
    return any(x is not None for x in (s.mesh_vertices, s.backbone, s.obstacle_points, s.obstacle_shapes,
                                       s.goal_position, s.plan))


def _translucent(archetype, color, fill=rr.components.FillMode.TransparentFillMajorWireframe, **fields):
    """Static style of a translucent solid (obstacle shapes: fill with major wireframe; goal region: solid)."""
    return archetype.from_fields(colors=[color], fill_mode=fill, **fields)


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


def _stream(app_id: str, recording_id: str, batcher_config: rr.ChunkBatcherConfig | None) -> rr.RecordingStream:
    rec = rr.RecordingStream(app_id, recording_id=recording_id, send_properties=False, batcher_config=batcher_config)
    rec.set_log_time_enabled(False)
    return rec


def _approach_arrow(position: np.ndarray, rotation: np.ndarray, tolerance: float) -> tuple[np.ndarray, np.ndarray]:
    """Origin and vector (3,) of the approach arrow: along the pose's z axis, ending at the goal."""
    vector = style.APPROACH_LENGTH * tolerance * rotation[:, 2]
    return position - vector, vector


@dataclass
class _Column:
    """Steps queued for one entity and set of components: index values, rows' lengths, component values."""

    entity: str
    archetype: Any
    steps: list[int] = field(default_factory=list)
    times: list[int] = field(default_factory=list)
    lengths: list[int] = field(default_factory=list)
    values: dict[str, list] = field(default_factory=dict)


class RerunSink:
    """Writes one run to `path` (.rrd) and/or streams it live to `live` (a `viewer.ViewerTarget`).

    `recording_id` should be derived from the run for reproducibility. `goal_tolerance` (m) draws
    the goal region; `safety_margin` and `goal_tolerance` are also drawn beside the distances.
    """

    def __init__(self, path: Path | None, *, app_id: str, recording_id: str, run_name: str,
                 safety_margin: float | None, goal_tolerance: float | None = None,
                 live: viewer.ViewerTarget | None = None):
        self._file = self._live = None
        if path is not None:
            self._file = _stream(app_id, recording_id, _batcher_config())
            self._file.save(str(path), default_blueprint=_blueprint(*_START))
        if live is not None:
            self._live = self._open_live(live, app_id, recording_id)
        self._live_url = None if live is None else live.url
        self._each(lambda rec: rec.send_recording_name(run_name))
        self._each(lambda rec: rec.log("/world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True))
        self._safety_margin = safety_margin
        self._goal_tolerance = goal_tolerance
        self._seen: set[tuple[str, str]] = set()
        self._pending: dict[tuple, _Column] = {}  # for the file, sent at each flush
        self._live_pending: dict[tuple, _Column] = {}  # for the viewer, sent after each step
        self._sent = _START  # the plots and 3D view of the blueprint sent last
        self._needed: tuple[frozenset[str], bool] | None = None  # those the steps so far have data for
        self._meshes = False

    @property
    def live(self) -> bool:
        """Whether the run is being streamed to a viewer."""
        return self._live is not None

    @staticmethod
    def _open_live(target: viewer.ViewerTarget, app_id: str, recording_id: str) -> rr.RecordingStream | None:
        """A stream connected to the viewer at `target` (spawned first if asked), or None after a warning."""
        rec = _stream(app_id, recording_id, None)  # rerun's default batcher: it ticks, so the viewer follows
        try:
            if target.spawn:
                rr.spawn(port=target.port, connect=False, executable_path=str(target.executable),
                         hide_welcome_screen=True, recording=rec)
                if not viewer.listening("127.0.0.1", target.port):
                    viewer.warn(f"the Rerun viewer started on port {target.port} does not accept connections; "
                                "recording to files only")
                    return None
            rec.connect_grpc(target.url, default_blueprint=_blueprint(*_START))
        except Exception as exc:  # rerun raises RuntimeError (spawn, connect); say why and go on without
            viewer.warn(f"cannot stream to a Rerun viewer at {target.url}: {exc}; recording to files only")
            return None
        return rec

    def _each(self, action) -> None:
        """`action(stream)` on the file stream, then on the live one (whose failure only ends the live view)."""
        if self._file is not None:
            action(self._file)
        if self._live is not None:
            try:
                action(self._live)
            except Exception as exc:
                self._lose_live(exc)

    def _lose_live(self, exc: Exception) -> None:
        viewer.warn(f"lost the Rerun viewer at {self._live_url}: {exc}; recording to files only")
        self._live, self._live_pending = None, {}

    def _lay_out(self, titles: frozenset[str], world: bool) -> None:
        """Keep the stored layout to a view for each kind of data the steps so far logged, no empty plot: the
        layout stored at the start is a closed-loop run's; where the steps need another, it is sent and made
        active (the viewer shows the last one made active)."""
        needed = (titles, world) if self._needed is None else (self._needed[0] | titles, self._needed[1] or world)
        self._needed = needed
        if needed != self._sent:
            blueprint = _blueprint(*needed)
            self._each(lambda rec: rec.send_blueprint(blueprint, make_active=True, make_default=True))
            self._sent = needed

    def log_run(self, meta: Mapping[str, Any]) -> None:
        values = rr.AnyValues(**schema.encode_meta(meta))
        self._each(lambda rec: rec.send_property(schema.RUN, values))

    def _log_at(self, step: int, sim_time_ns: int, entity: str, *archetypes) -> None:
        """Log now (not queued) at the step's time, to every stream."""
        duration = np.timedelta64(sim_time_ns, "ns")

        def log(rec: rr.RecordingStream) -> None:
            rec.set_time(schema.STEP_TIMELINE, sequence=step)
            rec.set_time(schema.SIM_TIME_TIMELINE, duration=duration)
            rec.log(entity, *archetypes)

        self._each(log)

    def _queue(self, s: Step, entity: str, archetype, static, **components) -> None:
        """Queue one step's `components` (arrays of equal length n_i) for `_send`.

        `static()` makes what is logged once as static the first time `archetype` is seen on
        `entity` (triangle indices, radii, series names ...): built only then. Steps with other
        components on the same entity (e.g. colours from some step on) queue separately.
        """
        if (entity, archetype.__name__) not in self._seen:
            style_ = static()
            self._each(lambda rec: rec.log(entity, style_, static=True))
            self._seen.add((entity, archetype.__name__))
        key = (entity, archetype.__name__, *components)
        for stream, pending in ((self._file, self._pending), (self._live, self._live_pending)):
            if stream is None:
                continue
            column = pending.setdefault(key, _Column(entity, archetype))
            column.steps.append(s.step)
            column.times.append(s.sim_time_ns)
            column.lengths.append(len(next(iter(components.values()))))
            for name, value in components.items():
                column.values.setdefault(name, []).append(value)

    @staticmethod
    def _send(rec: rr.RecordingStream, pending: dict[tuple, _Column]) -> None:
        """One `send_columns` per queued entity and set of components; empties `pending`."""
        for c in pending.values():
            indexes = [rr.TimeColumn(schema.STEP_TIMELINE, sequence=c.steps),
                       rr.TimeColumn(schema.SIM_TIME_TIMELINE, duration=np.array(c.times, dtype="timedelta64[ns]"))]
            data = {name: _concat(parts) for name, parts in c.values.items()}
            rec.send_columns(c.entity, indexes=indexes, columns=c.archetype.columns(**data).partition(c.lengths))
        pending.clear()

    def _send_queued(self) -> None:
        if self._file is not None:
            self._send(self._file, self._pending)

    def log_step(self, s: Step) -> None:
        """Queue one step (every entity given, the mesh included: Rerun logs it cheaply); stream it live."""
        self._lay_out(_plot_titles(s.metrics), self._meshes or _has_world(s))
        if s.mesh_vertices is not None:
            albedo = style.ROBOT_COLOR if s.link_colors is None else None  # albedo multiplies vertex colours
            topology = lambda: rr.Mesh3D.from_fields(  # noqa: E731
                triangle_indices=s.mesh_triangles, albedo_factor=albedo)
            colors = {}
            if s.link_colors is not None:
                per_link = s.mesh_vertices.shape[0] // s.link_colors.shape[0]
                colors["vertex_colors"] = np.repeat(style.pack_rgba(s.link_colors), per_link)
            self._queue(s, schema.MESH, rr.Mesh3D, topology, vertex_positions=s.mesh_vertices, **colors)
        if s.backbone is not None:
            colors = {} if s.link_colors is None else {"colors": style.pack_rgba(s.link_colors)}
            self._queue(s, schema.BACKBONE, rr.LineStrips3D,
                        lambda: rr.LineStrips3D.from_fields(radii=style.BACKBONE_RADIUS), strips=s.backbone, **colors)
        if s.obstacle_points is not None:
            self._queue(s, schema.OBSTACLE_POINTS, rr.Points3D,
                        lambda: rr.Points3D.from_fields(radii=style.OBSTACLE_POINT_RADIUS,
                                                        colors=style.OBSTACLE_POINT_COLOR),
                        positions=s.obstacle_points)
        if s.obstacle_shapes is not None:
            sh = s.obstacle_shapes
            self._queue(s, f"{schema.OBSTACLE_SHAPES}/spheres", rr.Ellipsoids3D,
                        lambda: _translucent(rr.Ellipsoids3D, style.OBSTACLE_COLOR), centers=sh.sphere_centers,
                        half_sizes=np.repeat(sh.sphere_radii[:, None], 3, axis=1))
            self._queue(s, f"{schema.OBSTACLE_SHAPES}/boxes", rr.Boxes3D,
                        lambda: _translucent(rr.Boxes3D, style.OBSTACLE_COLOR),
                        centers=sh.box_centers, half_sizes=sh.box_sizes / 2)
        self._log_goal(s)
        if s.plan is not None:
            self._queue(s, schema.PLAN, rr.LineStrips3D,
                        lambda: rr.LineStrips3D.from_fields(radii=style.PLAN_RADIUS, colors=style.PLAN_COLOR),
                        strips=s.plan[None])
            self._queue(s, schema.PLAN, rr.Points3D,
                        lambda: rr.Points3D.from_fields(radii=style.PLAN_KNOT_RADIUS, colors=style.PLAN_COLOR),
                        positions=s.plan)
        if s.state is not None:
            for key in schema.STATE_FIELDS:
                flat = s.state[key].ravel()
                names = lambda: rr.SeriesLines(names=schema.state_columns(key, flat.size))  # noqa: E731
                self._queue(s, f"{schema.STATE}/{key}", rr.Scalars, names, scalars=flat)
        for name, value in s.metrics.items():
            self._queue(s, f"{schema.METRICS}/{name}", rr.Scalars, lambda: rr.SeriesLines(names=[name]),
                        scalars=np.array([value]))
        for entity, label, value in ((schema.SAFETY_MARGIN, "safety margin", self._safety_margin),
                                     (schema.GOAL_TOLERANCE, "goal tolerance", self._goal_tolerance)):
            if value is not None:
                self._queue(s, entity, rr.Scalars, lambda: rr.SeriesLines(names=[label]),  # noqa: B023 (called now)
                            scalars=np.array([value]))
        if self._live is not None:
            try:
                self._send(self._live, self._live_pending)
            except Exception as exc:
                self._lose_live(exc)

    def _log_goal(self, s: Step) -> None:
        """The goal point (a pose: its frame, with the point at the origin) and, with a tolerance, its region
        and the approach arrow of a pose."""
        if s.goal_position is None:
            return
        point_style = {"radii": style.GOAL_POINT_RADIUS, "colors": style.GOAL_COLOR}
        if s.goal_rotation is not None:
            self._log_at(s.step, s.sim_time_ns, schema.GOAL,
                         rr.Transform3D(translation=s.goal_position, mat3x3=s.goal_rotation),
                         rr.Points3D(np.zeros((1, 3)), **point_style))
        else:
            self._queue(s, schema.GOAL, rr.Points3D, lambda: rr.Points3D.from_fields(**point_style),
                        positions=s.goal_position[None])
        tol = self._goal_tolerance
        if tol is None:
            return
        region = (*style.GOAL_COLOR, style.GOAL_REGION_ALPHA)
        self._queue(s, _REGION, rr.Ellipsoids3D,
                    lambda: _translucent(rr.Ellipsoids3D, region, rr.components.FillMode.Solid,
                                         half_sizes=[(tol, tol, tol)]),
                    centers=s.goal_position[None])
        if s.goal_rotation is not None:
            origin, vector = _approach_arrow(s.goal_position, s.goal_rotation, tol)
            self._queue(s, _APPROACH, rr.Arrows3D,
                        lambda: rr.Arrows3D.from_fields(radii=style.APPROACH_RADIUS, colors=style.GOAL_COLOR),
                        origins=origin[None], vectors=vector[None])

    def log_meshes(self, meshes) -> None:
        """The world's still meshes, (vertices (V, 3), faces (F, 3)) each, as static translucent solids."""
        for i, (vertices, faces) in enumerate(meshes):
            mesh = rr.Mesh3D(vertex_positions=vertices, triangle_indices=faces, albedo_factor=style.OBSTACLE_COLOR)
            self._each(lambda rec, i=i, mesh=mesh: rec.log(f"{schema.OBSTACLE_MESHES}/{i}", mesh, static=True))
        self._meshes = True
        if self._needed is not None:
            self._lay_out(frozenset(), True)

    def log_text(self, message: str, level: str, step: int, sim_time_ns: int) -> None:
        self._log_at(step, sim_time_ns, schema.LOG,
                     rr.TextLog(message, level=_LEVELS.get(level.lower(), level.upper())))

    def flush(self) -> None:
        """Write what is queued to the file and wait for it; start (never wait for) the live stream's flush."""
        self._send_queued()
        if self._file is not None:
            self._file.flush()
        if self._live is not None:
            try:
                self._live.flush(timeout_sec=0.0)
            except Exception as exc:
                self._lose_live(exc)

    def close(self, outcome: Mapping[str, Any]) -> None:
        """Write the outcome property, then flush and finalise the file (footer); end the live stream."""
        values = rr.AnyValues(**schema.encode_meta(outcome))
        self._each(lambda rec: rec.send_property("outcome", values))
        self._send_queued()
        if self._file is not None:
            self._file.flush()
            self._file.disconnect()
        if self._live is not None:
            try:
                self._live.flush(timeout_sec=_LIVE_CLOSE_TIMEOUT_S)
            except Exception as exc:
                self._lose_live(exc)
            else:
                self._live.disconnect()
