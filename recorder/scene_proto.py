"""`foxglove.SceneUpdate` messages with many points, encoded with NumPy.

Building one `foxglove.messages.Point3` per vertex is slow for a robot mesh of thousands of
vertices; writing the protobuf wire format of the repeated points (and of the packed
triangle indices) directly from arrays costs a small fraction of that. The small parts (entity
id, frame, timestamp, colour, line type) are still encoded by foxglove-sdk: protobuf lets
serialised fields be concatenated, so the result is exactly a `foxglove.SceneUpdate` with one
`SceneEntity` holding the given primitives.

Field numbers (foxglove schemas): SceneUpdate.entities = 2; SceneEntity.spheres = 9, .lines = 11,
.triangles = 12; LinePrimitive.points = 5; TriangleListPrimitive.points = 2, .colors = 4, .indices = 5
(packed fixed32); Point3 x = 1, y = 2, z = 3 (double); Color r = 1, g = 2, b = 3, a = 4 (double).
"""

from __future__ import annotations

import numpy as np
from foxglove import messages as fm

ENTITY_SPHERES, ENTITY_LINES, ENTITY_TRIANGLES = 9, 11, 12
LINE_POINTS, TRIANGLE_POINTS, TRIANGLE_COLORS, TRIANGLE_INDICES = 5, 2, 4, 5
_LEN = 2  # protobuf wire type "length-delimited"
_F64 = 1  # wire type "64-bit"

# One Point3 inside a repeated field: tag, length 27, then x, y, z each as tag + 8 bytes.
_POINT_DTYPE = np.dtype(
    [("tag", "u1"), ("len", "u1"), ("tx", "u1"), ("x", "<f8"), ("ty", "u1"), ("y", "<f8"), ("tz", "u1"), ("z", "<f8")]
)

# One Color inside a repeated field: tag, length 36, then r, g, b, a each as tag + 8 bytes.
_COLOR_DTYPE = np.dtype(
    [("tag", "u1"), ("len", "u1"), ("tr", "u1"), ("r", "<f8"), ("tg", "u1"), ("g", "<f8"), ("tb", "u1"), ("b", "<f8"),
     ("ta", "u1"), ("a", "<f8")]
)


def _varint(n: int) -> bytes:
    out = bytearray()
    while True:
        byte, n = n & 0x7F, n >> 7
        if n:
            out.append(byte | 0x80)
        else:
            out.append(byte)
            return bytes(out)


def _header(field: int, length: int) -> bytes:
    """Tag and length prefix of a length-delimited field."""
    return _varint(field << 3 | _LEN) + _varint(length)


def encode_points(points: np.ndarray, field: int) -> memoryview:
    """(N, 3) points -> the bytes of a repeated Point3 field (doubles) with field number `field`."""
    p = np.asarray(points, dtype=np.float64)
    buf = np.empty(p.shape[0], dtype=_POINT_DTYPE)
    buf["tag"] = field << 3 | _LEN
    buf["len"] = 27
    buf["tx"], buf["ty"], buf["tz"] = 1 << 3 | _F64, 2 << 3 | _F64, 3 << 3 | _F64
    buf["x"], buf["y"], buf["z"] = p[:, 0], p[:, 1], p[:, 2]
    return buf.view(np.uint8).data  # a byte view: no copy, len() in bytes


def encode_colors(rgb: np.ndarray, field: int, repeat: int = 1, alpha: float = 1.0) -> memoryview:
    """RGB bytes (N, 3) -> the bytes of a repeated Color field with field number `field`, each colour
    `repeat` times in a row (N * repeat colours; e.g. one per vertex of each link)."""
    c = np.asarray(rgb, dtype=np.float64) / 255.0
    buf = np.empty(c.shape[0], dtype=_COLOR_DTYPE)
    buf["tag"] = field << 3 | _LEN
    buf["len"] = 36
    buf["tr"], buf["tg"], buf["tb"], buf["ta"] = 1 << 3 | _F64, 2 << 3 | _F64, 3 << 3 | _F64, 4 << 3 | _F64
    buf["r"], buf["g"], buf["b"], buf["a"] = c[:, 0], c[:, 1], c[:, 2], alpha
    return np.repeat(buf, repeat).view(np.uint8).data


def encode_indices(triangles: np.ndarray) -> bytes:
    """(F, 3) triangle vertex indices -> the bytes of TriangleListPrimitive.indices (packed fixed32)."""
    data = np.ascontiguousarray(triangles, dtype="<u4").tobytes()
    return _header(TRIANGLE_INDICES, len(data)) + data


def encode_scene_update(entity: fm.SceneEntity, primitives: list[tuple[int, list]]) -> bytes:
    """Serialised SceneUpdate holding `entity` (id, frame, timestamp ...) plus `primitives`.

    primitives: (SceneEntity field number, [byte parts of one primitive]), e.g.
    (ENTITY_LINES, [LinePrimitive(color=...).encode(), encode_points(p, LINE_POINTS)]).
    """
    parts = [entity.encode()]
    for field, prim in primitives:
        parts += [_header(field, sum(len(p) for p in prim)), *prim]
    return b"".join([_header(2, sum(len(p) for p in parts)), *parts])  # the only copy of the payload
