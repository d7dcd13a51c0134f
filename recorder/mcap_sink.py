"""MCAP sink through foxglove-sdk: Foxglove's standard schemas for display, JSON for data.

Topics (= `recorder.schema` names):
- `/world/robot/mesh`, `/world/robot/backbone`, `/world/obstacles/shapes`, `/world/plan`: foxglove.SceneUpdate
  (frame "world"); with link clearances the mesh has per-vertex colours and each backbone line its
  link's colour (`recorder.style`); the plan is a thick line strip with a small sphere at each knot;
  `/world/obstacles/points`: foxglove.PointCloud (x, y, z float32); `/world/obstacles/meshes`: the
  world's still meshes, one foxglove.SceneUpdate each at time 0 (entity ``mesh<i>``, a triangle list);
  `/world/goal`: foxglove.FrameTransform world -> goal; with a goal tolerance, `/world/goal_marker`:
  foxglove.SceneUpdate with the goal region (a translucent sphere of that radius) and, for a pose
  goal, an arrow along its z axis ending at the goal; `/log`: foxglove.Log;
- `/metrics`, `/state`, `/outcome`: JSON with the schemas of `recorder.schema`;
- run metadata: MCAP metadata record `run` ({key: JSON text});
- on close, MCAP metadata record `summary` (`recorder.summary`): the outcome and per-metric statistics
  of /metrics, indexed in the summary section so a reader gets it without opening a chunk.
Every message's log_time is the step's sim_time in ns (no wall clock), so a run is reproducible.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Mapping

import foxglove
import numpy as np
from foxglove import channels as fc
from foxglove import messages as fm
from foxglove.mcap import MCAPWriteOptions

from recorder import schema, style, summary
from recorder.events import Step
from recorder.scene_proto import (ENTITY_LINES, ENTITY_SPHERES, ENTITY_TRIANGLES, LINE_POINTS, TRIANGLE_COLORS,
                                  TRIANGLE_POINTS, encode_colors, encode_indices, encode_points, encode_scene_update)

_FRAME = "world"
# zstd level 2 in the logging thread, chosen with bench/recording_cost.py (docs/experiments.md): cheaper than
# the default level 3, and its 1 MiB window (512 KiB at level 1) still reaches the previous step's triangle
# indices when the mesh carries per-vertex colours.
_WRITE_OPTIONS = MCAPWriteOptions(compression_level=2, compression_threads=0)


def _color(rgba) -> fm.Color:
    """RGB(A) bytes -> foxglove Color (components in [0, 1])."""
    r, g, b, a = (*(c / 255 for c in rgba), 1.0)[:4]
    return fm.Color(r=r, g=g, b=b, a=a)


_MESH_COLOR = _color(style.ROBOT_COLOR)
_LINE_COLOR = fm.Color(r=0.1, g=0.3, b=0.9, a=1.0)
_PLAN_COLOR = _color(style.PLAN_COLOR)
_OBSTACLE_COLOR = _color(style.OBSTACLE_COLOR)
_GOAL_COLOR = _color(style.GOAL_COLOR)
_REGION_COLOR = _color((*style.GOAL_COLOR, style.GOAL_REGION_ALPHA))
#: Turns foxglove's arrow direction (+x of its pose) into +z: a rotation by -90 degrees about y.
_X_TO_Z = np.array([[0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]])
_LEVELS = {"debug": fm.LogLevel.Debug, "info": fm.LogLevel.Info, "warning": fm.LogLevel.Warning,
           "warn": fm.LogLevel.Warning, "error": fm.LogLevel.Error, "critical": fm.LogLevel.Fatal}


def _timestamp(ns: int) -> fm.Timestamp:
    return fm.Timestamp(sec=ns // 1_000_000_000, nsec=ns % 1_000_000_000)


def _vector3(v) -> fm.Vector3:
    x, y, z = (float(c) for c in v)
    return fm.Vector3(x=x, y=y, z=z)


def _quaternion(r: np.ndarray | None) -> fm.Quaternion:
    """Rotation matrix (3, 3) (None: identity) -> unit quaternion (branch on the largest diagonal term)."""
    if r is None:
        return fm.Quaternion(x=0.0, y=0.0, z=0.0, w=1.0)
    m = np.asarray(r, dtype=np.float64)
    t = np.trace(m)
    if t > 0:
        s = 2.0 * np.sqrt(t + 1.0)
        w, x, y, z = 0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s
    else:
        i = int(np.argmax(np.diag(m)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * np.sqrt(1.0 + m[i, i] - m[j, j] - m[k, k])
        q = np.empty(3)
        q[i], q[j], q[k] = 0.25 * s, (m[j, i] + m[i, j]) / s, (m[k, i] + m[i, k]) / s
        w = (m[k, j] - m[j, k]) / s
        x, y, z = q
    return fm.Quaternion(x=float(x), y=float(y), z=float(z), w=float(w))


def _entity(entity_id: str, ns: int) -> fm.SceneEntity:
    return fm.SceneEntity(id=entity_id, frame_id=_FRAME, timestamp=_timestamp(ns))


def _lines(polylines, ns: int, entity_id: str, color: fm.Color, thickness: float, colors=None,
           extra: tuple = ()) -> bytes:
    """A SceneUpdate with one line strip per (K, 3) polyline, in `color` or its own of `colors` (RGB bytes);
    `extra`: more (field, [bytes]) primitives of the entity."""
    line = fm.LinePrimitiveLineType.LineStrip
    if colors is None:
        heads = [fm.LinePrimitive(type=line, color=color, thickness=thickness).encode()] * len(polylines)
    else:
        heads = [fm.LinePrimitive(type=line, color=_color(c), thickness=thickness).encode() for c in colors.tolist()]
    return encode_scene_update(_entity(entity_id, ns),
                               [(ENTITY_LINES, [h, encode_points(p, LINE_POINTS)]) for h, p in zip(heads, polylines)]
                               + list(extra))


def _mesh(vertices: np.ndarray, indices: bytes, ns: int, link_colors: np.ndarray | None) -> bytes:
    """A SceneUpdate with the robot mesh as one triangle list (indices from `encode_indices`): in the robot's
    colour, or with each link's vertices in its colour of `link_colors` (M, 3)."""
    if link_colors is None:
        parts = [fm.TriangleListPrimitive(color=_MESH_COLOR).encode()]
    else:
        parts = [encode_colors(link_colors, TRIANGLE_COLORS, repeat=vertices.shape[0] // link_colors.shape[0])]
    parts += [encode_points(vertices, TRIANGLE_POINTS), indices]
    return encode_scene_update(_entity("robot", ns), [(ENTITY_TRIANGLES, parts)])


def _knots(plan: np.ndarray) -> list:
    """A sphere at each knot of the plan, as SceneEntity.spheres primitives."""
    size = _vector3((2 * style.PLAN_KNOT_RADIUS,) * 3)
    return [(ENTITY_SPHERES, [fm.SpherePrimitive(pose=fm.Pose(position=_vector3(p)), size=size,
                                                 color=_PLAN_COLOR).encode()]) for p in plan]


def _goal_marker(position: np.ndarray, rotation: np.ndarray | None, tolerance: float, ns: int) -> fm.SceneUpdate:
    """The goal region (sphere of radius `tolerance`) and, for a pose, the approach arrow along its z axis."""
    region = fm.SpherePrimitive(pose=fm.Pose(position=_vector3(position)), size=_vector3((2 * tolerance,) * 3),
                                color=_REGION_COLOR)
    arrows = []
    if rotation is not None:
        length = style.APPROACH_LENGTH * tolerance
        tail = position - length * rotation[:, 2]
        d = 2 * style.APPROACH_RADIUS
        head = min(3 * d, length / 2)
        pose = fm.Pose(position=_vector3(tail), orientation=_quaternion(rotation @ _X_TO_Z))
        arrows.append(fm.ArrowPrimitive(pose=pose, shaft_length=length - head, shaft_diameter=d, head_length=head,
                                        head_diameter=2 * d, color=_GOAL_COLOR))
    entity = fm.SceneEntity(id="goal", frame_id=_FRAME, timestamp=_timestamp(ns), spheres=[region], arrows=arrows)
    return fm.SceneUpdate(entities=[entity])


def _shapes(sh, ns: int) -> fm.SceneUpdate:
    spheres = [
        fm.SpherePrimitive(pose=fm.Pose(position=_vector3(c)), size=_vector3((2 * r,) * 3), color=_OBSTACLE_COLOR)
        for c, r in zip(sh.sphere_centers, sh.sphere_radii)
    ]
    cubes = [
        fm.CubePrimitive(pose=fm.Pose(position=_vector3(c)), size=_vector3(s), color=_OBSTACLE_COLOR)
        for c, s in zip(sh.box_centers, sh.box_sizes)
    ]
    entity = fm.SceneEntity(id="obstacles", frame_id=_FRAME, timestamp=_timestamp(ns), spheres=spheres,
                            cubes=cubes)
    return fm.SceneUpdate(entities=[entity])


def _point_cloud(points: np.ndarray, ns: int) -> fm.PointCloud:
    f32 = fm.PackedElementFieldNumericType.Float32
    fields = [fm.PackedElementField(name=n, offset=4 * i, type=f32) for i, n in enumerate("xyz")]
    return fm.PointCloud(
        timestamp=_timestamp(ns), frame_id=_FRAME, pose=fm.Pose(position=_vector3((0, 0, 0)),
                                                                  orientation=fm.Quaternion(x=0, y=0, z=0, w=1)),
        point_stride=12, fields=fields, data=np.ascontiguousarray(points, dtype="<f4").tobytes(),
    )


class McapSink:
    """Writes one run to `path` (.mcap) with its own foxglove `Context` (so parallel runs never mix).

    mesh_every: write the robot mesh on steps with `step % mesh_every == 0` (it is most of the cost).
    goal_tolerance: metres; when given, the goal region is written to `/world/goal_marker`.
    """

    def __init__(self, path: Path, *, overwrite: bool, mesh_every: int = 1, goal_tolerance: float | None = None):
        self._ctx = foxglove.Context()
        self._writer = foxglove.open_mcap(str(path), allow_overwrite=overwrite, context=self._ctx,
                                         writer_options=_WRITE_OPTIONS)
        ctx = self._ctx
        # Mesh and lines are encoded by `scene_proto` (raw protobuf bytes of foxglove.SceneUpdate).
        self._mesh = foxglove.Channel(schema.MESH, schema=fm.SceneUpdate.get_schema(), message_encoding="protobuf",
                                      context=ctx)
        self._backbone = foxglove.Channel(schema.BACKBONE, schema=fm.SceneUpdate.get_schema(),
                                          message_encoding="protobuf", context=ctx)
        self._plan = foxglove.Channel(schema.PLAN, schema=fm.SceneUpdate.get_schema(), message_encoding="protobuf",
                                      context=ctx)
        self._shapes = fc.SceneUpdateChannel(schema.OBSTACLE_SHAPES, context=ctx)
        self._meshes = foxglove.Channel(schema.OBSTACLE_MESHES, schema=fm.SceneUpdate.get_schema(),
                                        message_encoding="protobuf", context=ctx)
        self._points = fc.PointCloudChannel(schema.OBSTACLE_POINTS, context=ctx)
        self._goal = fc.FrameTransformChannel(schema.GOAL, context=ctx)
        self._goal_tolerance = goal_tolerance
        self._goal_marker = None if goal_tolerance is None else fc.SceneUpdateChannel(schema.GOAL_MARKER, context=ctx)
        self._log = fc.LogChannel(schema.LOG, context=ctx)
        self._metrics = foxglove.Channel(schema.METRICS, schema=schema.METRICS_SCHEMA, context=ctx)
        self._state = foxglove.Channel(schema.STATE, schema=schema.STATE_SCHEMA, context=ctx)
        self._outcome = foxglove.Channel(schema.OUTCOME, schema=schema.OUTCOME_SCHEMA, context=ctx)
        self._mesh_every = mesh_every
        self._indices: bytes | None = None  # the triangle indices, encoded once
        self._last_ns = 0
        self._rows: list[dict] = []  # the /metrics rows written, for the summary record

    def log_run(self, meta: Mapping[str, Any]) -> None:
        self._writer.write_metadata(schema.RUN, schema.encode_meta(meta))

    def log_step(self, s: Step) -> None:
        """Write one step; the mesh only when `step % mesh_every == 0`."""
        ns = self._last_ns = s.sim_time_ns
        if s.mesh_vertices is not None and s.step % self._mesh_every == 0:
            if self._indices is None:
                self._indices = encode_indices(s.mesh_triangles)
            self._mesh.log(_mesh(s.mesh_vertices, self._indices, ns, s.link_colors), log_time=ns)
        if s.backbone is not None:
            self._backbone.log(_lines(s.backbone, ns, "backbone", _LINE_COLOR, 2 * style.BACKBONE_RADIUS,
                                      s.link_colors), log_time=ns)
        if s.obstacle_points is not None:
            self._points.log(_point_cloud(s.obstacle_points, ns), log_time=ns)
        if s.obstacle_shapes is not None:
            self._shapes.log(_shapes(s.obstacle_shapes, ns), log_time=ns)
        if s.goal_position is not None:
            tf = fm.FrameTransform(timestamp=_timestamp(ns), parent_frame_id=_FRAME, child_frame_id="goal",
                                   translation=_vector3(s.goal_position), rotation=_quaternion(s.goal_rotation))
            self._goal.log(tf, log_time=ns)
            if self._goal_marker is not None:
                self._goal_marker.log(_goal_marker(s.goal_position, s.goal_rotation, self._goal_tolerance, ns),
                                      log_time=ns)
        if s.plan is not None:
            self._plan.log(_lines([s.plan], ns, "plan", _PLAN_COLOR, 2 * style.PLAN_RADIUS, extra=_knots(s.plan)),
                           log_time=ns)
        head = {"step": s.step, "sim_time": s.sim_time}
        if s.state is not None:
            body = {k: s.state[k].tolist() for k in schema.STATE_FIELDS}
            self._state.log(json.dumps({**head, **body}).encode(), log_time=ns)
        metrics = {k: schema.json_float(v) for k, v in s.metrics.items()}
        self._metrics.log(json.dumps({**head, **metrics}).encode(), log_time=ns)
        self._rows.append({"step": s.step, **metrics})

    def log_meshes(self, meshes) -> None:
        """The world's still meshes, (vertices (V, 3), faces (F, 3)) each: one SceneUpdate at time 0, an
        entity ``mesh<i>`` with one triangle list per mesh."""
        for i, (vertices, faces) in enumerate(meshes):
            parts = [fm.TriangleListPrimitive(color=_OBSTACLE_COLOR).encode(), encode_points(vertices, TRIANGLE_POINTS),
                     encode_indices(faces)]
            self._meshes.log(encode_scene_update(_entity(f"mesh{i}", 0), [(ENTITY_TRIANGLES, parts)]), log_time=0)

    def log_text(self, message: str, level: str, step: int, sim_time_ns: int) -> None:
        msg = fm.Log(timestamp=_timestamp(sim_time_ns), level=_LEVELS.get(level.lower(), fm.LogLevel.Unknown),
                     message=message, name=f"step {step}")
        self._log.log(msg, log_time=sim_time_ns)

    def flush(self) -> None:
        self._writer.flush()

    def close(self, outcome: Mapping[str, Any]) -> None:
        """Write the outcome message (at the last step's time), the `summary` metadata record and close the
        file (summary section and footer)."""
        self._outcome.log(json.dumps(dict(outcome)).encode(), log_time=self._last_ns)
        self._writer.write_metadata(summary.RECORD, summary.encode(outcome, self._rows))
        self._writer.close()
