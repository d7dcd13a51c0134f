"""Obstacles, their motion and the world that holds them.

All positions in metres, times in seconds, world frame = robot base frame
(first tangent +z). Obstacles:

* :class:`MovingSphere`: centre ``c + v tri(t)``, ``tri`` the integral of the
  paper's periodic sign (+1 on ``[0, h)``, -1 on ``[h, 2h)``, ...), i.e. the
  triangle wave ``h - |t mod 2h - h|`` (``tri(t) = t`` when ``h`` is infinite).
* :class:`Box` (static, axis aligned), :class:`MeshObstacle` (static triangle
  mesh, checked by :mod:`scenarios.mesh_check`) and :class:`CloudObstacle`
  (static points; its points are the truth), the last two read from users'
  files by :func:`scenarios.obstacle_file.load_obstacle`.

What the controller sees of a world is :mod:`scenarios.observe`; the exact
distances are :mod:`scenarios.truth`; the judge of a step is
:mod:`scenarios.judge`.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from typing import TYPE_CHECKING

import jax
import jax.numpy as jnp
import numpy as np

from scenarios.mesh_check import MeshError, check_mesh, triangle_areas

if TYPE_CHECKING:
    from scenarios.mesh_index import MeshIndex

OBSERVE_MODES = ("surface", "centres")


class WorldError(ValueError):
    """A world or obstacle file that cannot be used (the message names it)."""


# ----------------------------------------------------------------------------- obstacles


def finite_vector(value, name: str, owner: str) -> tuple[float, ...]:
    """A finite 3-vector as a tuple of floats, or WorldError naming it."""
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise WorldError(f"{owner}.{name} must be 3 numbers, got {value!r}") from None
    if arr.shape != (3,) or not np.all(np.isfinite(arr)):
        raise WorldError(f"{owner}.{name} must be 3 finite numbers, got {value!r}")
    return tuple(float(x) for x in arr)


def _positive(value, name: str, owner: str, allow_inf: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise WorldError(f"{owner}.{name} must be a number, got {value!r}")
    value = float(value)
    if not value > 0 or (math.isinf(value) and not allow_inf) or math.isnan(value):
        raise WorldError(f"{owner}.{name} must be > 0{'' if allow_inf else ' and finite'}, got {value!r}")
    return value


def _rows(value, width: int, dtype, name: str, owner: str) -> tuple[tuple, ...]:
    """An (N, width) array as a tuple of tuples, or WorldError naming it."""
    arr = np.asarray(value, dtype=dtype)
    if arr.ndim != 2 or arr.shape[1] != width or len(arr) == 0:
        raise WorldError(f"{owner}.{name} must have shape (N, {width}) with N >= 1, got {arr.shape}")
    if dtype is np.float64 and not np.all(np.isfinite(arr)):
        raise WorldError(f"{owner}.{name} contains NaN or inf")
    return tuple(tuple(row) for row in arr.tolist())


def triangle_wave(t, half_period):
    """Integral of the periodic sign (+1 on [0, h), -1 on [h, 2h), ...): ``h - |t mod 2h - h|``.

    numpy (float64) for numpy or Python inputs, JAX for JAX arrays (traceable).

    Args:
      t: time(s), s.  half_period: h (...,), s; infinite = no flip (returns t).
    Returns:
      array broadcast of t and h, s.
    """
    xp = jnp if isinstance(t, jax.Array) or isinstance(half_period, jax.Array) else np
    t, h = xp.asarray(t), xp.asarray(half_period)
    finite = xp.isfinite(h)
    safe_h = xp.where(finite, h, 1.0)
    phase = xp.mod(t, 2.0 * safe_h)
    return xp.where(finite, safe_h - xp.abs(phase - safe_h), t)


@dataclasses.dataclass(frozen=True)
class MovingSphere:
    """A sphere moving with velocity +v on [0, h), -v on [h, 2h), ... (the sign flips every half period).

    Attributes:
      centre: (3,) position at t = 0, m.  radius: m (> 0).
      velocity: (3,) m/s (zero = static).  half_period: h, s (> 0; inf = never flips).
    """

    centre: tuple[float, float, float]
    radius: float
    velocity: tuple[float, float, float] = (0.0, 0.0, 0.0)
    half_period: float = math.inf

    def __post_init__(self):
        object.__setattr__(self, "centre", finite_vector(self.centre, "centre", "MovingSphere"))
        object.__setattr__(self, "velocity", finite_vector(self.velocity, "velocity", "MovingSphere"))
        object.__setattr__(self, "radius", _positive(self.radius, "radius", "MovingSphere"))
        object.__setattr__(self, "half_period",
                           _positive(self.half_period, "half_period", "MovingSphere", allow_inf=True))

    def position(self, t: float) -> np.ndarray:
        """Centre at time t, (3,) m."""
        tri = float(triangle_wave(float(t), self.half_period))
        return np.asarray(self.centre) + tri * np.asarray(self.velocity)

    @property
    def speed(self) -> float:
        """|v|, m/s (constant: only the sign flips)."""
        return float(np.linalg.norm(self.velocity))


@dataclasses.dataclass(frozen=True)
class Box:
    """A static axis-aligned box: centre (3,) m and full edge lengths size (3,) m (> 0)."""

    centre: tuple[float, float, float]
    size: tuple[float, float, float]

    def __post_init__(self):
        object.__setattr__(self, "centre", finite_vector(self.centre, "centre", "Box"))
        size = finite_vector(self.size, "size", "Box")
        if min(size) <= 0:
            raise WorldError(f"Box.size must be > 0 in every axis, got {size}")
        object.__setattr__(self, "size", size)


def _tuple_repr(self) -> str:
    fields = ", ".join(f"{f.name}=<{len(getattr(self, f.name))} rows>" if isinstance(getattr(self, f.name), tuple)
                       else f"{f.name}={getattr(self, f.name)!r}" for f in dataclasses.fields(self))
    return f"{type(self).__name__}({fields})"


@dataclasses.dataclass(frozen=True, repr=False, eq=False)
class MeshObstacle:
    """A static triangle mesh, already placed: vertices (V, 3) m, faces (F, 3) vertex indices.

    Checked when made (:func:`scenarios.mesh_check.check_mesh`: MeshError for a mesh the judge
    cannot be exact on, MeshWarning for an open one); ``name`` (optional) says where it came from.
    ``closed``: whether it bounds a solid. Equal only to itself.
    """

    vertices: np.ndarray
    faces: np.ndarray
    name: str = ""

    def __repr__(self) -> str:
        return f"MeshObstacle({self.name or 'unnamed'}: {len(self.vertices)} vertices, {len(self.faces)} faces)"

    def __post_init__(self):
        try:
            checked = check_mesh(self.vertices, self.faces, self.name or "MeshObstacle")
        except MeshError as err:
            raise WorldError(str(err)) from None
        for field in ("vertices", "faces"):
            value = getattr(checked, field)
            value.setflags(write=False)
            object.__setattr__(self, field, value)
        object.__setattr__(self, "_checked", checked)

    @property
    def closed(self) -> bool:
        """Whether the faces are closed surfaces (``scenarios.mesh_check``): the mesh bounds a solid."""
        return self._checked.closed

    @property
    def component_vertex(self) -> np.ndarray:
        """One vertex (K, 3) m of each connected component."""
        return self._checked.component_vertex

    @property
    def component_low(self) -> np.ndarray:
        """Lower corners (K, 3) m of the components' boxes."""
        return self._checked.component_low

    @property
    def component_high(self) -> np.ndarray:
        """Upper corners (K, 3) m of the components' boxes."""
        return self._checked.component_high

    @functools.cached_property
    def triangles(self) -> np.ndarray:
        """(F, 3, 3) corner positions of every face, m."""
        return self.vertices[self.faces]

    @functools.cached_property
    def area(self) -> float:
        """Surface area, m^2."""
        return float(triangle_areas(self.triangles).sum())

    @functools.cached_property
    def index(self) -> MeshIndex:
        """Its bounding-volume hierarchy (built on first use; warp is imported then: slow to import)."""
        from scenarios.mesh_index import MeshIndex

        return MeshIndex(self.vertices, self.faces)


@dataclasses.dataclass(frozen=True, repr=False)
class CloudObstacle:
    """A static bare point cloud, already placed: points (P, 3) m; its points are the truth."""

    points: tuple[tuple[float, float, float], ...]
    name: str = ""

    __repr__ = _tuple_repr

    def __post_init__(self):
        object.__setattr__(self, "points", _rows(self.points, 3, np.float64, "points", "CloudObstacle"))


@dataclasses.dataclass(frozen=True)
class World:
    """The obstacles of a scenario and how the controller observes them.

    Attributes:
      spheres, boxes, meshes, clouds: tuples of :class:`MovingSphere`, :class:`Box`,
        :class:`MeshObstacle`, :class:`CloudObstacle`. Distances come in this order.
      density: observed points per square metre on box faces and mesh surfaces (> 0).
      sphere_points: observed points per sphere surface (>= 1; observe="surface").
      observe: "surface" or "centres" (sphere centres only; see :attr:`margin_extra`).
      cloud_voxel: clouds observed one point per occupied cube of this edge, m (a dense scan
        thinned, ``scenarios.observe.thinned``); None: every point.
    """

    spheres: tuple = ()
    boxes: tuple = ()
    meshes: tuple = ()
    clouds: tuple = ()
    density: float = 4.0
    sphere_points: int = 30
    observe: str = "surface"
    cloud_voxel: float | None = None

    def __post_init__(self):
        for name, kind in (("spheres", MovingSphere), ("boxes", Box), ("meshes", MeshObstacle),
                           ("clouds", CloudObstacle)):
            items = getattr(self, name)
            if isinstance(items, (str, bytes)) or not hasattr(items, "__iter__"):
                raise WorldError(f"World.{name} must be a sequence of {kind.__name__}, got {items!r}")
            items = tuple(items)
            for item in items:
                if not isinstance(item, kind):
                    raise WorldError(f"World.{name} must hold {kind.__name__} objects, got {item!r}")
            object.__setattr__(self, name, items)
        object.__setattr__(self, "density", _positive(self.density, "density", "World"))
        if isinstance(self.sphere_points, bool) or not isinstance(self.sphere_points, (int, np.integer)) \
                or self.sphere_points < 1:
            raise WorldError(f"World.sphere_points must be an integer >= 1, got {self.sphere_points!r}")
        if self.observe not in OBSERVE_MODES:
            raise WorldError(f"World.observe must be one of {OBSERVE_MODES}, got {self.observe!r}")
        if self.cloud_voxel is not None:
            object.__setattr__(self, "cloud_voxel", _positive(self.cloud_voxel, "cloud_voxel", "World"))

    def scaled(self, factor: float) -> "World":
        """The world scaled by ``factor`` (> 0) about the origin (the robot's base): every position,
        size and speed times ``factor``, the density over its square, so the same points are observed."""
        if factor == 1.0:
            return self
        scale = lambda v: tuple(factor * x for x in v)  # noqa: E731
        return dataclasses.replace(
            self,
            spheres=tuple(dataclasses.replace(s, centre=scale(s.centre), radius=factor * s.radius,
                                              velocity=scale(s.velocity)) for s in self.spheres),
            boxes=tuple(Box(scale(b.centre), scale(b.size)) for b in self.boxes),
            meshes=tuple(MeshObstacle(factor * m.vertices, m.faces, m.name) for m in self.meshes),
            clouds=tuple(CloudObstacle(factor * np.asarray(c.points), c.name) for c in self.clouds),
            density=self.density / factor**2,
            cloud_voxel=None if self.cloud_voxel is None else factor * self.cloud_voxel)

    @property
    def margin_extra(self) -> float:
        """Radius the controller adds to its safety margin: the largest sphere radius when
        spheres are observed by their centres, else 0 (m)."""
        if self.observe == "centres" and self.spheres:
            return max(s.radius for s in self.spheres)
        return 0.0

    @property
    def n_obstacles(self) -> int:
        """Number of obstacles (the length of :func:`true_distances`)."""
        return len(self.spheres) + len(self.boxes) + len(self.meshes) + len(self.clouds)

    def sphere_centres(self, t: float) -> np.ndarray:
        """(S, 3) sphere centres at time t, m."""
        return self.sphere_track(np.asarray([t], np.float64))[0]

    def sphere_track(self, times: np.ndarray) -> np.ndarray:
        """(T, S, 3) sphere centres at each of ``times`` (T,) s, m."""
        times = np.asarray(times, np.float64)
        if not self.spheres:
            return np.zeros((len(times), 0, 3))
        centre, velocity = (np.array([getattr(s, name) for s in self.spheres]) for name in ("centre", "velocity"))
        half = np.array([s.half_period for s in self.spheres])
        return centre[None] + triangle_wave(times[:, None], half[None])[..., None] * velocity[None]

    @functools.cached_property
    def max_speed(self) -> float:
        """Largest obstacle speed, m/s (0 without spheres)."""
        return max((s.speed for s in self.spheres), default=0.0)
