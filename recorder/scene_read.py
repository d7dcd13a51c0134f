"""The recorded geometry of chosen steps of one .mcap recording (for the snapshot figures);
reached as ``recorder.read.load_snapshots``.

``recorder.read.load_run`` gives metrics, state and outcome, not the scene; this reads the scene topics
(``recorder.schema``: backbone, observed points, obstacle shapes, goal, plan) of a few steps with
the ``mcap`` reader and the protobuf schemas stored in the file. Steps are matched by their log time
(the recorder logs every event of a step at its ``sim_time``).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
from mcap.reader import make_reader
from mcap_protobuf.decoder import DecoderFactory

from recorder import RecorderError, schema

_TOPICS = (schema.BACKBONE, schema.OBSTACLE_POINTS, schema.OBSTACLE_SHAPES, schema.GOAL, schema.PLAN)


@dataclasses.dataclass(frozen=True)
class Snapshot:
    """The scene at one step. backbone: one (K, 3) polyline per link; points: (P, 3) observed cloud;
    spheres: (S, 4) centre and radius; boxes: (B, 6) centre and size; goal: (3,); plan: (H, 3) or None. m."""

    step: int
    sim_time: float
    backbone: list[np.ndarray]
    points: np.ndarray
    spheres: np.ndarray
    boxes: np.ndarray
    goal: np.ndarray | None
    plan: np.ndarray | None


def _xyz(points) -> np.ndarray:
    return np.array([[p.x, p.y, p.z] for p in points], dtype=np.float64).reshape(-1, 3)


def _decode(topic: str, msg, parts: dict) -> None:
    if topic == schema.OBSTACLE_POINTS:
        parts["points"] = np.frombuffer(msg.data, dtype="<f4").reshape(-1, 3).astype(np.float64)
    elif topic == schema.GOAL:
        parts["goal"] = np.array([msg.translation.x, msg.translation.y, msg.translation.z])
    elif topic in (schema.BACKBONE, schema.PLAN):
        lines = [_xyz(line.points) for entity in msg.entities for line in entity.lines]
        parts["backbone" if topic == schema.BACKBONE else "plan"] = lines if topic == schema.BACKBONE else lines[0]
    elif topic == schema.OBSTACLE_SHAPES:
        entity = msg.entities[0] if msg.entities else None
        spheres = [] if entity is None else entity.spheres
        cubes = [] if entity is None else entity.cubes
        parts["spheres"] = np.array([[s.pose.position.x, s.pose.position.y, s.pose.position.z, s.size.x / 2]
                                     for s in spheres]).reshape(-1, 4)
        parts["boxes"] = np.array([[c.pose.position.x, c.pose.position.y, c.pose.position.z,
                                    c.size.x, c.size.y, c.size.z] for c in cubes]).reshape(-1, 6)


def snapshots(path: str | Path, times: dict[int, float]) -> dict[int, Snapshot]:
    """The scene at each of ``times`` ({step: sim_time s}, e.g. from ``load_run(path).metrics``).

    Raises RecorderError when the file is not a readable .mcap."""
    path = Path(path)
    if path.suffix != ".mcap":
        raise RecorderError(f"{path}: the scene is read from .mcap recordings")
    wanted = {schema.sim_time_ns(t): k for k, t in times.items()}
    parts: dict[int, dict] = {k: {} for k in times}
    factory = DecoderFactory()
    try:
        with open(path, "rb") as f:
            for schema_, channel, message in make_reader(f).iter_messages(topics=list(_TOPICS)):
                step = wanted.get(message.log_time)
                if step is None:
                    continue
                decoded = factory.decoder_for(channel.message_encoding, schema_)(message.data)
                _decode(channel.topic, decoded, parts[step])
    except Exception as exc:  # corrupt content
        raise RecorderError(f"{path} is not a readable MCAP recording: {exc}") from None
    empty3, empty4, empty6 = np.zeros((0, 3)), np.zeros((0, 4)), np.zeros((0, 6))
    return {k: Snapshot(k, times[k], p.get("backbone", []), p.get("points", empty3), p.get("spheres", empty4),
                        p.get("boxes", empty6), p.get("goal"), p.get("plan"))
            for k, p in parts.items()}
