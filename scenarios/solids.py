"""The solids the confined-space worlds are built of, as closed triangle meshes, their seeds and density.

Pieces of one obstacle overlap by ``OVERLAP``, each a closed mesh of its own that shares no vertex
with another; the obstacle is their union, one :class:`scenarios.world.MeshObstacle` with a
component per piece.
"""

from __future__ import annotations

import jax
import numpy as np
import trimesh

from scenarios.world import MeshObstacle

OVERLAP = 0.01  # m
#: Points per square metre the confined worlds' surfaces are observed at: at the paper's 4 the holes
#: between samples (about 1.1 m across) are as wide as an opening the robot fits through, which no
#: model of the points can tell apart; at 16 they are about half as wide.
DENSITY = 16.0


def slab(low, high) -> trimesh.Trimesh:
    """The box between corners ``low`` and ``high`` (3,) m, grown by OVERLAP / 2 on every side."""
    low, high = np.asarray(low, np.float64) - OVERLAP / 2, np.asarray(high, np.float64) + OVERLAP / 2
    return trimesh.creation.box(extents=high - low).apply_translation((low + high) / 2)


def tube(start, end, inner: float, outer: float, sections: int = 48) -> trimesh.Trimesh:
    """A pipe (a closed annular solid) from ``start`` to ``end`` (3,) m, radii ``inner`` < ``outer`` m."""
    start, end = np.asarray(start, np.float64), np.asarray(end, np.float64)
    axis = end - start
    pipe = trimesh.creation.annulus(r_min=inner, r_max=outer, height=float(np.linalg.norm(axis)), sections=sections)
    pipe.apply_transform(trimesh.geometry.align_vectors([0.0, 0.0, 1.0], axis / np.linalg.norm(axis)))
    return pipe.apply_translation((start + end) / 2)


def pillar(base, radius: float, height: float, sections: int = 32) -> trimesh.Trimesh:
    """An upright cylinder standing on ``base`` (3,) m."""
    column = trimesh.creation.cylinder(radius=radius, height=height, sections=sections)
    return column.apply_translation(np.asarray(base, np.float64) + [0.0, 0.0, height / 2])


def obstacle(pieces, name: str) -> MeshObstacle:
    """One mesh obstacle of the pieces (closed meshes), named for messages."""
    merged = trimesh.util.concatenate(list(pieces))
    return MeshObstacle(merged.vertices, merged.faces, name)


def draw(env_seed: int, ranges) -> np.ndarray:
    """One number uniform in each ``(low, high)`` of ``ranges``, from ``env_seed`` (reproducible)."""
    low, high = np.asarray(ranges, np.float64).T
    u = np.asarray(jax.random.uniform(jax.random.PRNGKey(env_seed), (len(low),)), np.float64)
    return low + (high - low) * u
