"""What a triangle mesh must be for the judge to be exact on it, checked once when it is made.

Errors (:class:`MeshError`, one line naming the mesh): no faces, NaN or infinite vertices, faces
indexing missing vertices, more than ``MAX_FACES`` faces, or a degenerate face (zero area, or a
sliver the BVH skips, :data:`SLIVER_RATIO`) whose long edge is not an edge
of a proper face: its points would be missed. Degenerate faces whose long edge is shared with a
proper face add no point to the surface; they are dropped with a warning.

Warnings (:class:`MeshWarning`, one line): an open surface (an edge traversed more often in one
direction than in the other: a hole's rim, a fin, faces wound inconsistently) has no inside; the
judge takes it as a surface, exactly. A closed mesh (every edge traversed as often each way, once
equal vertices are shared: one closed surface, or solids touching at their vertices, edges or faces)
bounds a solid, the points of winding number at least one half.
"""

from __future__ import annotations

import dataclasses
import warnings

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

#: Faces whose doubled area is below this fraction of their summed squared edge lengths are skipped by
#: Warp's closest-point search in ``scenarios.mesh_index`` (its sliver test, 1e-6, with a margin for
#: float32): the mesh checks treat them as degenerate.
SLIVER_RATIO = 4e-6


MAX_FACES = 4_000_000


class MeshError(ValueError):
    """A mesh the judge cannot be exact on (the message names it and the problem)."""


class MeshWarning(UserWarning):
    """A mesh the judge takes differently from what its file may mean (the message says how)."""


@dataclasses.dataclass(frozen=True)
class CheckedMesh:
    """A checked mesh: vertices (V, 3) float64 m, faces (F, 3) int64, closed, and per connected
    component one vertex (K, 3) and its box (K, 3) lower and upper, m."""

    vertices: np.ndarray
    faces: np.ndarray
    closed: bool
    component_vertex: np.ndarray
    component_low: np.ndarray
    component_high: np.ndarray


def triangle_areas(triangles: np.ndarray) -> np.ndarray:
    """(..., 3, 3) triangles -> (...,) areas, m^2."""
    return 0.5 * np.linalg.norm(np.cross(triangles[..., 1, :] - triangles[..., 0, :],
                                         triangles[..., 2, :] - triangles[..., 0, :]), axis=-1)


def _edge_keys(a: np.ndarray, b: np.ndarray, n: int) -> np.ndarray:
    """An integer per undirected edge (a, b) of vertex indices < n."""
    return np.minimum(a, b) * n + np.maximum(a, b)


def _drop_degenerate(vertices: np.ndarray, faces: np.ndarray, name: str) -> np.ndarray:
    """The faces without the degenerate ones (module docstring), or MeshError."""
    tri = vertices[faces]
    edges = tri[:, [1, 2, 0]] - tri  # edge k runs from corner k to corner k + 1
    squared = np.sum(edges * edges, axis=-1)
    doubled = 2.0 * triangle_areas(tri)
    bad = doubled <= SLIVER_RATIO * squared.sum(axis=-1)
    if not bad.any():
        return faces
    if bad.all():
        raise MeshError(f"mesh {name!r}: every face is degenerate (no area)")
    n = len(vertices)
    good = faces[~bad]
    proper = np.unique(np.concatenate([_edge_keys(good[:, k], good[:, (k + 1) % 3], n) for k in range(3)]))
    longest = np.argmax(squared[bad], axis=1)
    worst = faces[bad]
    rows = np.arange(len(worst))
    keys = _edge_keys(worst[rows, longest], worst[rows, (longest + 1) % 3], n)
    loose = ~np.isin(keys, proper)
    if loose.any():
        raise MeshError(f"mesh {name!r}: {int(loose.sum())} degenerate faces (no area) are not edges of the "
                        "surface; repair the mesh")
    warnings.warn(MeshWarning(f"mesh {name!r}: dropped {int(bad.sum())} degenerate faces (no area)"), stacklevel=3)
    return good


def _closed(faces: np.ndarray, n: int) -> bool:
    """Every undirected edge traversed by the faces as often in one direction as in the other.

    Then the faces are a sum of closed surfaces (their oriented boundary is empty), and the winding
    number, the sum of the faces' signed solid angles over 4 pi, is an integer off them that counts
    the solids around a point: exact for one closed manifold surface (each edge in two faces, once
    each way) and for solids that touch at shared vertices, edges or faces (an edge in four faces)."""
    a, b = faces.ravel(), faces[:, [1, 2, 0]].ravel()
    _, edge = np.unique(_edge_keys(a, b, n), return_inverse=True)
    return not np.any(np.bincount(edge.ravel(), weights=np.where(a < b, 1.0, -1.0)))


def _signed_volume(vertices: np.ndarray, faces: np.ndarray) -> float:
    """The volume a closed surface bounds, negative when its faces are wound inwards, m^3."""
    a, b, c = (vertices[faces[:, k]] for k in range(3))
    return float(np.sum(a * np.cross(b, c)) / 6.0)


def _components(vertices: np.ndarray, faces: np.ndarray):
    """One vertex (K, 3) and the box (K, 3), (K, 3) of each connected component of the faces."""
    n = len(vertices)
    rows = np.repeat(faces[:, 0], 2)
    cols = faces[:, 1:].ravel()
    graph = coo_matrix((np.ones(len(rows), np.int8), (rows, cols)), shape=(n, n))
    count, label = connected_components(graph, directed=False)
    used = np.unique(faces)
    label = label[used]
    low = np.full((count, 3), np.inf)
    high = np.full((count, 3), -np.inf)
    np.minimum.at(low, label, vertices[used])
    np.maximum.at(high, label, vertices[used])
    first = np.full(count, -1)
    first[label[::-1]] = used[::-1]
    present = first >= 0
    return vertices[first[present]], low[present], high[present]


def check_mesh(vertices, faces, name: str) -> CheckedMesh:
    """Check a mesh (module docstring); ``name`` says where it came from, for messages."""
    vertices = np.asarray(vertices, np.float64)
    faces = np.asarray(faces)
    if vertices.ndim != 2 or vertices.shape[1] != 3 or len(vertices) == 0:
        raise MeshError(f"mesh {name!r}: vertices must have shape (V, 3) with V >= 1, got {vertices.shape}")
    if faces.ndim != 2 or faces.shape[1] != 3 or len(faces) == 0:
        raise MeshError(f"mesh {name!r} has no faces (faces shape {faces.shape})")
    if len(faces) > MAX_FACES:
        raise MeshError(f"mesh {name!r} has {len(faces):,} faces, more than the {MAX_FACES:,} the judge takes; "
                        "simplify it")
    if not np.all(np.isfinite(vertices)):
        raise MeshError(f"mesh {name!r} has NaN or infinite vertex coordinates")
    if not np.issubdtype(faces.dtype, np.integer):
        raise MeshError(f"mesh {name!r}: faces must be vertex indices, got {faces.dtype}")
    faces = faces.astype(np.int64)
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise MeshError(f"mesh {name!r}: faces index vertices outside [0, {len(vertices) - 1}]")
    # files such as STL repeat a vertex for every face that holds it: share equal ones
    vertices, shared = np.unique(vertices, axis=0, return_inverse=True)
    faces = shared.ravel()[faces]
    faces = _drop_degenerate(vertices, faces, name)
    closed = _closed(faces, len(vertices))
    if closed and _signed_volume(vertices, faces) < 0:
        faces = faces[:, ::-1]  # wound inwards: the same solid, its faces turned outwards
    if not closed:
        warnings.warn(MeshWarning(f"mesh {name!r} is open or wound inconsistently (an edge in more of its faces "
                                  "one way than the other): it has no inside and is judged as a surface"), stacklevel=3)
    return CheckedMesh(vertices, faces, closed, *_components(vertices, faces))
