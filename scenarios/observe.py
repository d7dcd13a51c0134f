"""The controller's view of a world: points drawn on its surfaces once per episode.

Box faces get ``round(density * area)`` uniform points each; a mesh gets
``round(density * area)`` points over its surface, triangles drawn by area and
points uniform on them (linear in the face count: fast for 10^6 faces); all
cloud points, or one per occupied cube of ``cloud_voxel`` (:func:`thinned`);
``sphere_points`` points on each sphere, fixed in the sphere's frame so they move
with it (``observe="surface"``), or the sphere centres only (``observe="centres"``;
the controller adds :attr:`World.margin_extra`).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from scenarios.mesh_check import triangle_areas
from scenarios.world import World, WorldError

#: The most points a world may be observed at: the controller scores every one each step (the worlds
#: here: hundreds to a few thousand).
MAX_OBSERVED = 50_000


def surface_count(area, density: float):
    """The points observed on ``area`` m^2 (a float or an array) at ``density`` per m^2: the area times
    the density, rounded (an int, or an int array)."""
    return np.rint(density * np.asarray(area)).astype(int)[()]


def _box_faces(centre, size) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The six faces of a box: centres (6, 3), two edge half-vectors (6, 2, 3), areas (6,)."""
    c, h = np.asarray(centre, np.float64), 0.5 * np.asarray(size, np.float64)
    centres, half_edges, areas = [], [], []
    for k in range(3):
        i, j = (k + 1) % 3, (k + 2) % 3
        for sign in (-1.0, 1.0):
            centres.append(c + sign * h[k] * np.eye(3)[k])
            half_edges.append([h[i] * np.eye(3)[i], h[j] * np.eye(3)[j]])
            areas.append(4.0 * h[i] * h[j])
    return np.array(centres), np.array(half_edges), np.array(areas)


def _as_key(key):
    if isinstance(key, (int, np.integer)) and not isinstance(key, bool):
        return jax.random.PRNGKey(int(key))
    return key


class Observer:
    """The controller's view of a world: random surface points drawn once (see :func:`make_observer`).

    ``observe(t)`` -> (P, 3) float32: sphere points (or centres) at time t first,
    then the static points (box faces, meshes, clouds). ``n_points`` = P.
    """

    def __init__(self, world: World, sphere_offsets: np.ndarray, static_points: np.ndarray):
        self.world = world
        self._offsets = sphere_offsets  # (S, K, 3), K = 1 and zero offsets for "centres"
        self.static_points = static_points.astype(np.float32)
        self.n_points = self._offsets.shape[0] * self._offsets.shape[1] + len(self.static_points)

    def observe(self, t: float) -> np.ndarray:
        """The observed cloud at time t, (P, 3) float32, m."""
        moving = (self.world.sphere_centres(t)[:, None, :] + self._offsets).reshape(-1, 3)
        return np.concatenate([moving.astype(np.float32), self.static_points], axis=0)


def thinned(points: np.ndarray, voxel: float) -> np.ndarray:
    """One point (K, 3) of the points (P, 3) m in each occupied cube of edge ``voxel`` m of a grid
    through the origin, in the points' order: the one nearest the centroid of the cube's points (a
    real point, on the scanned surface, unlike the centroid at a corner; a tie goes to the first);
    ValueError for a voxel too small to index the cubes."""
    points = np.asarray(points, np.float64).reshape(-1, 3)
    if len(points) == 0:
        return points
    if np.max(np.abs(points)) / voxel >= 2.0**52:  # cube indices past float64's integers would merge cubes
        raise ValueError(f"voxel {voxel:g} m is too small for coordinates up to {np.max(np.abs(points)):g} m")
    _, group = np.unique(np.floor(points / voxel).astype(np.int64), axis=0, return_inverse=True)
    group = group.ravel()
    sizes = np.bincount(group)
    centroid = np.zeros((len(sizes), 3))
    np.add.at(centroid, group, points)
    centroid /= sizes[:, None]
    order = np.lexsort((np.sum((points - centroid[group]) ** 2, axis=1), group))
    first = order[np.r_[True, group[order][1:] != group[order][:-1]]]
    return points[np.sort(first)]


def observed_cloud(points, voxel: float | None) -> np.ndarray:
    """The observed points (K, 3) m of a cloud's points: all of them, or :func:`thinned` by ``voxel``."""
    points = np.asarray(points, np.float64)
    return points if voxel is None else thinned(points, voxel)


def make_observer(world: World, key) -> Observer:
    """Draw the observation of ``world`` once (key: jax.random key or int seed).

    Box faces get ``round(density * area)`` uniform points each; a mesh gets
    ``round(density * area)`` points, each on a triangle drawn by area and
    uniform on it; clouds are observed whole or thinned (:func:`thinned`); spheres ("surface") get
    ``sphere_points`` uniform directions times the radius, fixed in the
    sphere's frame, or ("centres") their centres.
    """
    if not isinstance(world, World):
        raise WorldError(f"make_observer needs a World, got {type(world).__name__}")
    k_box, k_mesh, k_tri, k_sphere = jax.random.split(_as_key(key), 4)
    faces = [_box_faces(b.centre, b.size) for b in world.boxes]
    mesh_areas = [triangle_areas(mesh.triangles) for mesh in world.meshes]
    area = sum(float(f[2].sum()) for f in faces) + sum(float(a.sum()) for a in mesh_areas)
    if world.density * area > MAX_OBSERVED:  # checked in floats: a huge density overflows the counts
        raise WorldError(f"{area:.4g} m^2 of surface at {world.density:g} points per m^2 is {world.density * area:.4g} "
                         f"observed points, more than {MAX_OBSERVED}: lower the density")
    parts = []
    if world.boxes:
        counts = surface_count(np.concatenate([f[2] for f in faces]), world.density)
        centres = np.concatenate([f[0] for f in faces])
        half_edges = np.concatenate([f[1] for f in faces])
        face = np.repeat(np.arange(len(counts)), counts)
        st = 2.0 * np.asarray(jax.random.uniform(k_box, (len(face), 2)), np.float64) - 1.0
        parts.append(centres[face] + st[:, :1] * half_edges[face, 0] + st[:, 1:] * half_edges[face, 1])
    for i, (mesh, areas) in enumerate(zip(world.meshes, mesh_areas)):
        tri = mesh.triangles
        n = int(surface_count(areas.sum(), world.density))
        k_pick, k_bary = jax.random.split(jax.random.fold_in(k_mesh, i))
        pick = np.asarray(jax.random.choice(k_pick, len(tri), (n,), p=jnp.asarray(areas / areas.sum())))
        ab = np.asarray(jax.random.uniform(k_bary, (n, 2)), np.float64)
        root = np.sqrt(ab[:, :1])
        a, b, c = tri[pick, 0], tri[pick, 1], tri[pick, 2]
        parts.append((1.0 - root) * a + root * (1.0 - ab[:, 1:]) * b + root * ab[:, 1:] * c)
    for cloud in world.clouds:
        parts.append(observed_cloud(cloud.points, world.cloud_voxel))
    static = np.concatenate(parts) if parts else np.zeros((0, 3))
    n_spheres = len(world.spheres)
    if world.observe == "centres":
        offsets = np.zeros((n_spheres, 1, 3))
    else:
        dirs = np.asarray(jax.random.normal(k_sphere, (n_spheres, world.sphere_points, 3)), np.float64)
        dirs /= np.linalg.norm(dirs, axis=-1, keepdims=True)
        radii = np.array([s.radius for s in world.spheres]).reshape(-1, 1, 1)
        offsets = dirs * radii
    return Observer(world, offsets, static)
