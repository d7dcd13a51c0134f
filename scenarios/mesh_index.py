"""A triangle mesh's bounding-volume hierarchy and the queries the judge asks of it (NVIDIA Warp).

Warp builds the BVH and runs the queries as compiled kernels, on the CPU here and unchanged on a
CUDA device: closest points (the unsigned distance), the winding-number side of a closed mesh,
and the faces whose boxes overlap given boxes. Positions in metres, float32 inside Warp.
"""

from __future__ import annotations

import functools
import os
import sys

import numpy as np
import warp as wp

wp.config.log_level = wp.LOG_ERROR  # no greeting, no compile times, no "no CUDA driver" on a CPU machine
_FAR = 1.0e6  # m: a query radius that holds every mesh the judge accepts


@wp.kernel
def _closest_kernel(mesh: wp.uint64, points: wp.array(dtype=wp.vec3), radius: wp.array(dtype=wp.float32),
                    out: wp.array(dtype=wp.vec3), found: wp.array(dtype=wp.int32)):
    i = wp.tid()
    query = wp.mesh_query_point_no_sign(mesh, points[i], radius[i])
    found[i] = wp.where(query.result, 1, 0)
    if query.result:
        out[i] = wp.mesh_eval_position(mesh, query.face, query.u, query.v)


@wp.kernel
def _inside_kernel(mesh: wp.uint64, points: wp.array(dtype=wp.vec3), out: wp.array(dtype=wp.int32)):
    i = wp.tid()
    query = wp.mesh_query_point_sign_winding_number(mesh, points[i], _FAR)
    out[i] = wp.where(query.sign < 0.0, 1, 0)


@wp.kernel
def _overlap_kernel(mesh: wp.uint64, lower: wp.array(dtype=wp.vec3), upper: wp.array(dtype=wp.vec3),
                    hits: wp.array(dtype=wp.int32), count: wp.array(dtype=wp.int32)):
    i = wp.tid()
    query = wp.mesh_query_aabb(mesh, lower[i], upper[i])
    face = int(0)
    while wp.mesh_query_aabb_next(query, face):
        slot = wp.atomic_add(count, 0, 1)
        if slot < hits.shape[0]:
            hits[slot] = face


@functools.lru_cache(maxsize=1)
def _device() -> str:
    """Warp's device, initialised once. Its native start-up says on stderr when a machine has no CUDA
    driver, which is no news to a CPU user: that line is held back (errors still raise)."""
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        with open(os.devnull, "w") as quiet:
            os.dup2(quiet.fileno(), 2)
            wp.init()
    finally:
        os.dup2(saved, 2)
        os.close(saved)
    return str(wp.get_preferred_device())


class MeshIndex:
    """The BVH of one mesh: vertices (V, 3) m, faces (F, 3) indices (checked by the caller)."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray):
        self.device = _device()
        self._points = wp.array(np.asarray(vertices, np.float32), dtype=wp.vec3, device=self.device)
        self._faces = wp.array(np.asarray(faces, np.int32).ravel(), dtype=wp.int32, device=self.device)
        self.mesh = wp.Mesh(points=self._points, indices=self._faces, support_winding_number=True)

    def _vectors(self, points: np.ndarray):
        data = np.ascontiguousarray(points, np.float32).reshape(-1, 3)
        return wp.array(data, dtype=wp.vec3, device=self.device, copy=self.device != "cpu")

    def distance(self, points: np.ndarray, radius: np.ndarray | None = None):
        """The distance (P,) m from each of ``points`` (P, 3) to the mesh, capped at ``radius`` (P,) m
        (none = no cap), and the closest mesh points (P, 3) (NaN where the distance is the cap)."""
        if len(points) == 0:
            return np.zeros(0), np.zeros((0, 3))
        cap = np.full(len(points), _FAR) if radius is None else np.minimum(radius, _FAR)
        out = wp.zeros(len(points), dtype=wp.vec3, device=self.device)
        found = wp.zeros(len(points), dtype=wp.int32, device=self.device)
        wp.launch(_closest_kernel, dim=len(points),
                  inputs=[self.mesh.id, self._vectors(points),
                          wp.array(cap.astype(np.float32), device=self.device, copy=self.device != "cpu"), out, found],
                  device=self.device)
        hit = found.numpy().astype(bool)
        closest = np.where(hit[:, None], out.numpy().astype(np.float64), np.nan)
        distance = np.where(hit, np.linalg.norm(closest - points, axis=-1), cap)
        return distance, closest

    def inside(self, points: np.ndarray) -> np.ndarray:
        """Whether each of ``points`` (P, 3) lies inside the (closed) mesh, by its winding number, (P,) bool."""
        out = wp.empty(len(points), dtype=wp.int32, device=self.device)
        wp.launch(_inside_kernel, dim=len(points), inputs=[self.mesh.id, self._vectors(points), out],
                  device=self.device)
        return out.numpy().astype(bool)

    def faces_overlapping(self, lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
        """Indices of the faces whose bounding boxes overlap any box ``[lower_i, upper_i]`` (B, 3), sorted."""
        capacity = 4096
        while True:
            hits = wp.empty(capacity, dtype=wp.int32, device=self.device)
            count = wp.zeros(1, dtype=wp.int32, device=self.device)
            wp.launch(_overlap_kernel, dim=len(lower),
                      inputs=[self.mesh.id, self._vectors(lower), self._vectors(upper), hits, count],
                      device=self.device)
            n = int(count.numpy()[0])
            if n <= capacity:
                return np.unique(hits.numpy()[:n])
            capacity = n
