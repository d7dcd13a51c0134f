"""Obstacles from users' files: meshes and point clouds, checked before any judgement.

Errors are :class:`scenarios.world.WorldError`, one line naming the file and the problem; a mesh
that is open gets a one-line :class:`scenarios.mesh_check.MeshWarning` (see there).
"""

from __future__ import annotations

import os
import struct
import warnings

import numpy as np

from scenarios.mesh_check import MAX_FACES
from scenarios.pcd import read_pcd
from scenarios.world import CloudObstacle, MeshObstacle, WorldError, finite_vector


#: Rotations that turn each axis a file may hold as "up" into +z (proper: a mesh keeps its winding).
UP = {"z": np.eye(3), "-z": np.diag([1.0, -1.0, -1.0]),
      "y": np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]]), "-y": np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]]),
      "x": np.array([[0.0, 0, -1], [0, 1, 0], [1, 0, 0]]), "-x": np.array([[0.0, 0, 1], [0, 1, 0], [-1, 0, 0]])}


#: Metres per unit of length a file may be written in (CAD meshes are often in millimetres).
UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001, "in": 0.0254}


def load_obstacle(path, offset=(0.0, 0.0, 0.0), up: str = "z", units: str = "m") -> MeshObstacle | CloudObstacle:
    """Read an obstacle from a user's file written in ``units`` (a key of ``UNITS``), turn its ``up``
    axis (a key of ``UP``: glTF files are +y up by their standard) to +z, and shift it by ``offset``
    (3,) m.

    Meshes (.stl .obj .ply .off .glb ...) are read with trimesh (a scene is
    merged into one mesh) -> :class:`MeshObstacle`; a .ply without faces, a
    PCL .pcd (``scenarios.pcd``), an .xyz text file (x y z per line, extra
    columns ignored) or a .npy (P, 3) array -> :class:`CloudObstacle`, its
    points with a NaN or infinite coordinate (a scanner's invalid returns)
    dropped with a warning. Raises :class:`WorldError` naming the file.
    """
    import trimesh

    path = os.fspath(path)
    shift = np.asarray(finite_vector(offset, "offset", "load_obstacle"))
    if up not in UP:
        raise WorldError(f"up axis {up!r}: choose one of {', '.join(UP)}")
    if units not in UNITS:
        raise WorldError(f"units {units!r}: choose one of {', '.join(UNITS)}")
    column = np.argmax(np.abs(UP[up]), axis=1)  # each turn is a signed permutation: no inf * 0 of a product
    sign = UP[up][np.arange(3), column] * UNITS[units]

    def place(points: np.ndarray) -> np.ndarray:
        return points[:, column] * sign + shift

    name = os.path.basename(path)
    if not os.path.isfile(path):
        what = ("does not exist" if not os.path.exists(path) else "is a folder" if os.path.isdir(path)
                else "is not a regular file")
        raise WorldError(f"obstacle file {path!r} {what}")
    ext = os.path.splitext(path)[1].lower()
    _check_declared_faces(path, ext)
    try:
        if ext == ".npy":
            points = np.load(path, allow_pickle=False)
            return CloudObstacle(place(_cloud_array(points, path)), name)
        if ext == ".pcd":
            return CloudObstacle(place(_cloud_array(read_pcd(path), path)), name)
        if ext == ".xyz":
            with warnings.catch_warnings():  # an empty file: the shape check below says so, on one line
                warnings.simplefilter("ignore", UserWarning)
                points = np.loadtxt(path, dtype=np.float64, ndmin=2, comments="#")
            if points.ndim != 2 or points.shape[1] < 3:
                raise WorldError(f"obstacle file {path!r}: expected x y z per line, got shape {points.shape}")
            return CloudObstacle(place(_cloud_array(points[:, :3], path)), name)
        loaded = trimesh.load(path, process=False)
        if isinstance(loaded, trimesh.Scene):
            if not loaded.geometry:
                raise WorldError(f"obstacle file {path!r} holds no geometry")
            loaded = loaded.to_geometry() if hasattr(loaded, "to_geometry") else loaded.dump(concatenate=True)
        if isinstance(loaded, trimesh.PointCloud):
            return CloudObstacle(place(_cloud_array(loaded.vertices, path)), name)
        if isinstance(loaded, trimesh.Trimesh):
            if len(loaded.faces) == 0:
                return CloudObstacle(place(_cloud_array(loaded.vertices, path)), name)
            return MeshObstacle(place(np.asarray(loaded.vertices, np.float64)), np.asarray(loaded.faces), path)
        raise WorldError(f"obstacle file {path!r} holds a {type(loaded).__name__}, not a mesh or point cloud")
    except WorldError as err:
        if path in str(err):
            raise
        raise WorldError(f"obstacle file {path!r}: {err}") from None
    except Exception as err:  # any reader failure becomes one line naming the file
        first = str(err).splitlines()[0] if str(err) else type(err).__name__
        raise WorldError(f"cannot read obstacle file {path!r}: {first}") from None


def _cloud_array(points, path: str) -> np.ndarray:
    arr = np.asarray(points, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 3 or len(arr) == 0:
        raise WorldError(f"obstacle file {path!r}: expected (N, 3) points with N >= 1, got shape {arr.shape}")
    finite = np.all(np.isfinite(arr), axis=1)
    if not finite.all():  # a scanner's invalid returns (an organized cloud's pixels without one)
        warnings.warn(f"obstacle file {path!r}: dropped {int((~finite).sum())} invalid (NaN or infinite) points",
                      stacklevel=3)
        arr = arr[finite]
    if len(arr) == 0:
        raise WorldError(f"obstacle file {path!r} holds no point with finite coordinates")
    return arr


def _check_declared_faces(path: str, ext: str) -> None:
    """Refuse a binary STL or a PLY whose header declares more than MAX_FACES faces, before reading it."""
    with open(path, "rb") as handle:
        head = handle.read(4096)
    declared = None
    if ext == ".stl" and len(head) >= 84:
        count = struct.unpack("<I", head[80:84])[0]
        if os.path.getsize(path) == 84 + 50 * count:  # a binary STL: 50 bytes per face after the header
            declared = count
    elif ext == ".ply":
        for line in head.split(b"\n"):
            words = line.split()
            if words[:2] == [b"element", b"face"] and len(words) == 3 and words[2].isdigit():
                declared = int(words[2])
    if declared is not None and declared > MAX_FACES:
        raise WorldError(f"obstacle file {path!r} declares {declared:,} faces, more than the {MAX_FACES:,} the "
                         "judge takes; simplify the mesh")
