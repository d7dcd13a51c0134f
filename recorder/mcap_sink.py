"""MCAP sink through foxglove-sdk: Foxglove's standard schemas for display, JSON for data.

Topics (= `recorder.schema` names):
- `/world/robot/mesh`, `/world/robot/backbone`, `/world/obstacles/shapes`, `/world/plan`: foxglove.SceneUpdate
  (frame "world"); `/world/obstacles/points`: foxglove.PointCloud (x, y, z float32);
  `/world/goal`: foxglove.FrameTransform world -> goal; `/log`: foxglove.Log;
- `/metrics`, `/state`, `/outcome`: JSON with the schemas of `recorder.schema`;
- run metadata: MCAP metadata record `run` ({key: JSON text}).
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

from recorder import schema
from recorder.events import Step
from recorder.scene_proto import (ENTITY_LINES, ENTITY_TRIANGLES, LINE_POINTS, TRIANGLE_POINTS, encode_indices,
                                  encode_points, encode_scene_update)

_FRAME = "world"
# zstd level 1 in the logging thread: measured on 7-link runs, 1.5 ms/step instead of 2.5 ms for the
# default level, for 10 % larger files (bench/recorder.py).
_WRITE_OPTIONS = MCAPWriteOptions(compression_level=1, compression_threads=0)
_MESH_COLOR = fm.Color(r=0.75, g=0.75, b=0.8, a=1.0)
_LINE_COLOR = fm.Color(r=0.1, g=0.3, b=0.9, a=1.0)
_PLAN_COLOR = fm.Color(r=0.1, g=0.8, b=0.2, a=1.0)
_OBSTACLE_COLOR = fm.Color(r=0.9, g=0.3, b=0.2, a=0.5)
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


def _lines(polylines, ns: int, entity_id: str, color: fm.Color, thickness: float) -> bytes:
    """A SceneUpdate with one line strip per (K, 3) polyline."""
    head = fm.LinePrimitive(type=fm.LinePrimitiveLineType.LineStrip, color=color, thickness=thickness).encode()
    return encode_scene_update(_entity(entity_id, ns),
                               [(ENTITY_LINES, [head, encode_points(p, LINE_POINTS)]) for p in polylines])


def _mesh(vertices: np.ndarray, indices: bytes, ns: int) -> bytes:
    """A SceneUpdate with the robot mesh as one triangle list (indices from `encode_indices`)."""
    head = fm.TriangleListPrimitive(color=_MESH_COLOR).encode()
    return encode_scene_update(_entity("robot", ns),
                               [(ENTITY_TRIANGLES, [head, encode_points(vertices, TRIANGLE_POINTS), indices])])


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
    """

    def __init__(self, path: Path, *, overwrite: bool, mesh_every: int = 1):
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
        self._points = fc.PointCloudChannel(schema.OBSTACLE_POINTS, context=ctx)
        self._goal = fc.FrameTransformChannel(schema.GOAL, context=ctx)
        self._log = fc.LogChannel(schema.LOG, context=ctx)
        self._metrics = foxglove.Channel(schema.METRICS, schema=schema.METRICS_SCHEMA, context=ctx)
        self._state = foxglove.Channel(schema.STATE, schema=schema.STATE_SCHEMA, context=ctx)
        self._outcome = foxglove.Channel(schema.OUTCOME, schema=schema.OUTCOME_SCHEMA, context=ctx)
        self._mesh_every = mesh_every
        self._indices: bytes | None = None  # the triangle indices, encoded once
        self._last_ns = 0

    def log_run(self, meta: Mapping[str, Any]) -> None:
        self._writer.write_metadata("run", schema.encode_meta(meta))

    def log_step(self, s: Step) -> None:
        """Write one step; the mesh only when `step % mesh_every == 0`."""
        ns = self._last_ns = s.sim_time_ns
        if s.mesh_vertices is not None and s.step % self._mesh_every == 0:
            if self._indices is None:
                self._indices = encode_indices(s.mesh_triangles)
            self._mesh.log(_mesh(s.mesh_vertices, self._indices, ns), log_time=ns)
        if s.backbone is not None:
            self._backbone.log(_lines(s.backbone, ns, "backbone", _LINE_COLOR, 0.004), log_time=ns)
        if s.obstacle_points is not None:
            self._points.log(_point_cloud(s.obstacle_points, ns), log_time=ns)
        if s.obstacle_shapes is not None:
            self._shapes.log(_shapes(s.obstacle_shapes, ns), log_time=ns)
        if s.goal_position is not None:
            tf = fm.FrameTransform(timestamp=_timestamp(ns), parent_frame_id=_FRAME, child_frame_id="goal",
                                   translation=_vector3(s.goal_position), rotation=_quaternion(s.goal_rotation))
            self._goal.log(tf, log_time=ns)
        if s.plan is not None:
            self._plan.log(_lines([s.plan], ns, "plan", _PLAN_COLOR, 0.004), log_time=ns)
        head = {"step": s.step, "sim_time": s.sim_time}
        if s.state is not None:
            body = {k: s.state[k].tolist() for k in schema.STATE_FIELDS}
            self._state.log(json.dumps({**head, **body}).encode(), log_time=ns)
        metrics = {k: schema.json_float(v) for k, v in s.metrics.items()}
        self._metrics.log(json.dumps({**head, **metrics}).encode(), log_time=ns)

    def log_text(self, message: str, level: str, step: int, sim_time_ns: int) -> None:
        msg = fm.Log(timestamp=_timestamp(sim_time_ns), level=_LEVELS.get(level.lower(), fm.LogLevel.Unknown),
                     message=message, name=f"step {step}")
        self._log.log(msg, log_time=sim_time_ns)

    def flush(self) -> None:
        self._writer.flush()

    def close(self, outcome: Mapping[str, Any]) -> None:
        """Write the outcome message (at the last step's time) and close the file (summary and footer)."""
        self._outcome.log(json.dumps(dict(outcome)).encode(), log_time=self._last_ns)
        self._writer.close()
