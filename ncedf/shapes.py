"""Robot shape representations behind one interface (paper Sec. VI).

Every representation is a frozen dataclass registered as a JAX pytree (its
arrays and network parameters are leaves; its name and robot spec are static),
so it can be passed into jitted functions. All answer:

  ``min_distance(points (P, 3), arc (M, 3), mask=None) -> scalar``
  ``distances(points (P, 3), arc (M, 3)) -> (P,)``        (min over links)
  ``link_distances(points (P, 3), arc (M, 3)) -> (M, P)``
  ``prepare(arc) -> LinkGeometry`` and ``pair_distances(geom, points (K, 3),
  link (K,)) -> (K,)``: the distance of point k to link ``link[k]`` only, for a
  configuration prepared once. The MPPI broad phase uses this pair form.

All are pure and ``vmap``-able over configurations. Points are world points, m.

Representations, chosen by name with :func:`make_shape`:

* ``exact``: closed-form signed distance (``ncedf.geometry``); negative inside.
  The oracle, not in the paper.
* ``ncedf``: the learned N-CEDF composed through the kinematic chain (paper
  eq. 5-6).
* ``spheres`` / ``spheres:N``: N spheres per link (default 8) centred on the
  backbone, whose union encloses the link body (see :class:`SphereShape`).
  Distance = min over spheres of ``||p - c|| - R``.
* ``pointcloud:P``: P points on the robot surface (``ceil(P / M)`` per link),
  fixed surface coordinates mapped through the kinematics; distance = the
  smallest pairwise distance (unsigned, >= 0).
"""

from __future__ import annotations

import dataclasses
import functools
from typing import NamedTuple, Protocol, runtime_checkable

import jax
import jax.numpy as jnp
import numpy as np

from ncedf.geometry import (
    link_signed_distance,
    robot_link_signed_distances,
    robot_surface_points,
    sample_surface_coords,
)
from ncedf.robot import (
    RobotSpec,
    arc_lengths_to_config,
    arc_sagitta,
    backbone_points,
    bending_vector,
    forward_kinematics,
    link_transform,
    world_to_frame,
)

DEFAULT_SPHERES_PER_LINK = 8


class LinkGeometry(NamedTuple):
    """Per-configuration quantities a representation needs (a pytree).

    frames: (M + 1, 4, 4) forward kinematics (frames[i] = base of link i + 1).
    theta, phi: (M,) link configurations, rad.
    centres: (M, n, 3) world points (sphere centres or surface points), or None.
    radius: (M,) sphere radius per link, or None.
    """

    frames: jnp.ndarray
    theta: jnp.ndarray
    phi: jnp.ndarray
    centres: jnp.ndarray | None = None
    radius: jnp.ndarray | None = None


@runtime_checkable
class Shape(Protocol):
    """The interface every robot shape representation offers (see the module docstring).

    Implementations are frozen dataclasses registered as pytrees, so they pass
    into jitted functions; ``spec`` and ``name`` are static.
    """

    spec: RobotSpec
    name: str

    def min_distance(self, points: jnp.ndarray, arc: jnp.ndarray, mask=None) -> jnp.ndarray:
        """Smallest distance from the (unmasked) points (P, 3) to the robot at arc (M, 3); +inf if none, m.
        ``mask``: (P,), or (M, P) per link."""

    def distances(self, points: jnp.ndarray, arc: jnp.ndarray) -> jnp.ndarray:
        """(P,) distance from each point to the robot, m."""

    def link_distances(self, points: jnp.ndarray, arc: jnp.ndarray) -> jnp.ndarray:
        """(M, P) distance from each point to each link, m."""

    def prepare(self, arc: jnp.ndarray, frames=None) -> LinkGeometry:
        """Per-configuration geometry for ``pair_distances``."""

    def pair_distances(self, geom: LinkGeometry, points: jnp.ndarray, link: jnp.ndarray) -> jnp.ndarray:
        """(K,) distance of point k (K, 3) to link ``link[k]`` only, m."""

    def state_pair_distances(self, arcs, frames, points, link) -> jnp.ndarray:
        """``pair_distances`` for a batch of states (B..., M, 3), their frames and pairs (B..., K), m."""


def _sq_dist(p: jnp.ndarray, q: jnp.ndarray) -> jnp.ndarray:
    """Squared distances between ``p`` (..., A, 3) and ``q`` (..., B, 3): (..., A, B).

    Written per component so XLA fuses it with the following reduction (on a CPU much
    faster than materialising the (A, B, 3) differences).
    """
    out = 0.0
    for i in range(3):
        out = out + (p[..., :, None, i] - q[..., None, :, i]) ** 2
    return out


def _masked_min(d: jnp.ndarray, mask) -> jnp.ndarray:
    if mask is not None:
        d = jnp.where(mask, d, jnp.inf)
    return jnp.min(d, initial=jnp.inf)


class _Base:
    """Shared methods; subclasses define ``prepare``, ``pair_distances``, ``link_distances``."""

    def distances(self, points: jnp.ndarray, arc: jnp.ndarray) -> jnp.ndarray:
        """Distance from each world point to the robot (min over links), (P,), m."""
        return jnp.min(self.link_distances(points, arc), axis=0)

    def min_distance(self, points: jnp.ndarray, arc: jnp.ndarray, mask=None) -> jnp.ndarray:
        """Smallest distance from the (unmasked) points to the robot; +inf if none. ``mask``: (P,), or
        (M, P) for the points each link counts (``ncedf.mount``)."""
        if mask is not None and mask.ndim == 2:
            return _masked_min(self.link_distances(points, arc), mask)
        return _masked_min(self.distances(points, arc), mask)

    def state_pair_distances(self, arcs, frames, points, link):
        """``pair_distances`` for a batch of states: arcs (B..., M, 3), frames (B..., M + 1, 4, 4),
        points (B..., K, 3), link (B..., K) -> (B..., K)."""
        fn = lambda a, f, p, k: self.pair_distances(self.prepare(a, f), p, k)  # noqa: E731
        for _ in range(arcs.ndim - 2):
            fn = jax.vmap(fn)
        return fn(arcs, frames, points, link)

    def _base_geometry(self, arc: jnp.ndarray, frames=None) -> LinkGeometry:
        theta, phi = arc_lengths_to_config(arc, self.spec)
        frames = forward_kinematics(arc, self.spec) if frames is None else frames
        return LinkGeometry(frames, theta, phi)


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class ExactShape(_Base):
    """Closed-form signed distance to the link bodies (tube + end disks)."""

    spec: RobotSpec = dataclasses.field(metadata=dict(static=True))
    name: str = dataclasses.field(default="exact", metadata=dict(static=True))

    def prepare(self, arc, frames=None):
        """Per-configuration geometry; ``frames`` = forward kinematics if already known."""
        return self._base_geometry(arc, frames)

    def pair_distances(self, geom: LinkGeometry, points, link):
        local = world_to_frame(geom.frames[link], points)

        def one(p, th, ph, r):
            return link_signed_distance(p[None], th, ph, self.spec, r)[0]

        radius = jnp.broadcast_to(self.spec.radius_of(link), link.shape)
        return jax.vmap(one)(local, geom.theta[link], geom.phi[link], radius)

    def link_distances(self, points, arc):
        return robot_link_signed_distances(points, arc, self.spec)


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class NCEDFShape(_Base):
    """The learned N-CEDF: ``min_i Gamma_i(T_0i^-1 p, q_i)`` (paper eq. 5-6).

    ``model`` is an ``ncedf.model.NCEDF`` (a pytree; its parameters are leaves).
    """

    model: object
    spec: RobotSpec = dataclasses.field(metadata=dict(static=True))
    name: str = dataclasses.field(default="ncedf", metadata=dict(static=True))

    def prepare(self, arc, frames=None):
        """Per-configuration geometry; ``frames`` = forward kinematics if already known."""
        return self._base_geometry(arc, frames)

    def pair_distances(self, geom: LinkGeometry, points, link):
        """``model.link_distance`` of point k to link ``link[k]``, vectorised over the pairs.

        The same computation as ``NCEDF.link_distance`` (bending-plane or paper
        encoding, network, chord-bound clamp outside the training box), written
        for per-pair (theta, phi) so the network runs as one (K, D) batch
        instead of K batched matrix-vector products.
        """
        model = self.model
        local = world_to_frame(geom.frames[link], points)  # (K, 3)
        theta, phi = geom.theta[link], geom.phi[link]
        end = link_transform(geom.theta, geom.phi, model.spec)[:, :3, 3][link]  # (K, 3)
        return model.local_distance(local, theta, phi, end, arc_sagitta(theta, model.spec.length), link)

    def state_pair_distances(self, arcs, frames, points, link):
        """Batched pairs: the per-link quantities of all states are computed once and
        gathered per pair; the same computation as ``pair_distances``."""
        model = self.model
        theta_l, phi_l = arc_lengths_to_config(arcs, self.spec)  # (B..., M)
        end_l = link_transform(theta_l, phi_l, model.spec)[..., :3, 3]  # (B..., M, 3)

        def gather(per_link):  # (B..., M, ...) -> (B..., K, ...)
            index = link.reshape(link.shape + (1,) * (per_link.ndim - link.ndim))
            return jnp.take_along_axis(per_link, index, axis=link.ndim - 1)

        theta, phi = gather(theta_l), gather(phi_l)
        local = world_to_frame(gather(frames[..., :-1, :, :]), points)  # (B..., K, 3)
        batch = theta.shape
        return model.local_distance(
            local.reshape(-1, 3), theta.reshape(-1), phi.reshape(-1), gather(end_l).reshape(-1, 3),
            arc_sagitta(theta, model.spec.length).reshape(-1), link.reshape(-1),
        ).reshape(batch)

    def link_distances(self, points, arc):
        return self.model.robot_link_distances(points, arc)


def sphere_cover_radius(theta, spec: RobotSpec, per_link: int):
    """Radius of ``per_link`` equal spheres that cover a link bent by ``theta``.

    Centres sit on the backbone at arc lengths ``s_i = (i + 1/2) h``,
    ``h = L / n``. Claim: every point of the link body (tube of radius r around
    the backbone plus the flat end disks) lies within

        ``R = sqrt(r^2 + delta^2 (1 + r kappa))``,  ``delta = h / 2``,
        ``kappa = theta / L``,

    of some centre. Proof: a body point is ``q = b(s) + v`` with ``v`` normal to
    the backbone tangent ``T(s)`` and ``|v| <= r`` (the end disks are the cross
    sections at s = 0 and s = L). Take the centre ``c = b(s + t)`` with
    ``|t| <= delta`` (one exists for every s in [0, L]). In the Frenet frame at
    ``s`` (tangent T, normal N towards the centre of curvature),
    ``w = c - b(s) = (sin(kappa t) / kappa) T + ((1 - cos(kappa t)) / kappa) N``,
    so ``|w| <= |t|`` and, writing ``v = a N + b B``,
    ``|q - c|^2 = |v|^2 + |w|^2 - 2 a (1 - cos(kappa t)) / kappa
    <= r^2 + t^2 + 2 r kappa t^2 / 2``, using ``a >= -r`` and
    ``1 - cos x <= x^2 / 2``. Hence ``|q - c| <= R``. (kappa = 0 is the limit.)
    """
    delta = spec.length / (2.0 * per_link)
    kappa = jnp.asarray(theta) / spec.length
    r = spec.radius_of()  # theta (..., M) for a tapered robot
    return jnp.sqrt(r**2 + delta**2 * (1.0 + r * kappa))


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class SphereShape(_Base):
    """``per_link`` spheres per link centred on the backbone, covering the body.

    The radius is :func:`sphere_cover_radius` of the link's bend, so the union
    of the balls contains the link body. Consequences: for a point outside the
    union the reported distance ``min_i ||p - c_i|| - R`` is the distance to the
    union, hence never more than the exact distance to the body; for a point in
    the body it is <= 0. (Conservative: the robot looks fatter.)
    """

    spec: RobotSpec = dataclasses.field(metadata=dict(static=True))
    per_link: int = dataclasses.field(default=DEFAULT_SPHERES_PER_LINK, metadata=dict(static=True))
    name: str = dataclasses.field(default="spheres", metadata=dict(static=True))

    def prepare(self, arc, frames=None):
        """Per-configuration geometry; ``frames`` = forward kinematics if already known."""
        base = self._base_geometry(arc, frames)
        fractions = (jnp.arange(self.per_link) + 0.5) / self.per_link
        centres = backbone_points(bending_vector(arc, self.spec), base.frames[..., :-1, :, :], fractions,
                                  self.spec.length)
        radius = sphere_cover_radius(base.theta, self.spec, self.per_link)
        return base._replace(centres=centres, radius=radius)

    def pair_distances(self, geom: LinkGeometry, points, link):
        c = geom.centres[link]  # (K, n, 3)
        sq = _sq_dist(points[:, None, :], c)[:, 0, :]  # (K, n)
        return jnp.sqrt(jnp.min(sq, axis=-1)) - geom.radius[link]

    def link_distances(self, points, arc):
        geom = self.prepare(arc)
        sq = _sq_dist(points[None], geom.centres)  # (M, P, n)
        return jnp.sqrt(jnp.min(sq, axis=-1)) - geom.radius[:, None]


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class PointCloudShape(_Base):
    """Fixed surface coordinates ``coords`` (M, n, 3) mapped through the kinematics.

    Distance = the smallest Euclidean distance between the obstacle point and
    the link's surface points (unsigned; never below the exact distance for
    points outside the robot, since the samples lie on the surface).
    """

    coords: jnp.ndarray
    spec: RobotSpec = dataclasses.field(metadata=dict(static=True))
    name: str = dataclasses.field(default="pointcloud", metadata=dict(static=True))

    def surface_points(self, arc, frames=None):
        """The robot's surface samples in the world, (M, n, 3)."""
        return robot_surface_points(self.coords, arc, self.spec, frames)

    def prepare(self, arc, frames=None):
        """Per-configuration geometry; ``frames`` = forward kinematics if already known."""
        base = self._base_geometry(arc, frames)
        return base._replace(centres=self.surface_points(arc, base.frames))

    def pair_distances(self, geom: LinkGeometry, points, link):
        s = geom.centres[link]  # (K, n, 3)
        return jnp.sqrt(jnp.min(_sq_dist(points[:, None, :], s)[:, 0, :], axis=-1))

    def link_distances(self, points, arc):
        s = self.surface_points(arc)  # (M, n, 3)
        return jnp.sqrt(jnp.min(_sq_dist(points[None], s), axis=-1))


def rescaled(shape: Shape, spec: RobotSpec) -> Shape:
    """``shape`` for ``spec``, the same robot scaled: every representation's distances scale with it."""
    if isinstance(shape, NCEDFShape):
        return dataclasses.replace(shape, spec=spec, model=shape.model.rescaled(spec))
    return dataclasses.replace(shape, spec=spec)


REPRESENTATIONS = ("ncedf", "spheres", "pointcloud:P", "exact")


def _parse_count(name: str, text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise ValueError(f"representation {name!r}: {text!r} is not an integer count") from None
    if value < 1:
        raise ValueError(f"representation {name!r}: the count must be >= 1, got {value}")
    return value


def make_shape(
    name: str,
    spec: RobotSpec,
    *,
    model=None,
    spheres_per_link: int | None = None,
    seed: int = 0,
) -> Shape:
    """A shape representation by name.

    Args:
      name: ``"ncedf"``, ``"spheres"`` or ``"spheres:N"`` (N per link),
        ``"pointcloud:P"`` (P points over the whole robot, ``ceil(P / M)`` per
        link), or ``"exact"``.
      spec: the robot.
      model: for ``ncedf``, an ``NCEDF``; default ``ncedf.model.load_model()``.
        Its link geometry (length, radius, limits) must match ``spec``.
      spheres_per_link: for ``spheres`` without a count; default 8.
      seed: for ``pointcloud``, the key of the fixed surface coordinates.
    Raises:
      ValueError: unknown name, bad count, or a model trained for other links.
    """
    if not isinstance(name, str):
        raise ValueError(f"representation name must be a string, got {name!r}")
    kind, _, arg = name.partition(":")
    if kind == "exact" and not arg:
        return ExactShape(spec=spec)
    if kind == "ncedf" and not arg:
        if model is None:
            from ncedf.model import load_model

            model = load_model()
        mspec = model.spec
        for field in ("length", "radius", "l_min", "l_max"):
            ours, theirs = np.atleast_1d(getattr(mspec, field)), np.atleast_1d(getattr(spec, field))
            if ours.shape != theirs.shape or not np.allclose(ours, theirs, rtol=1e-6, atol=0.0):
                raise ValueError(
                    f"the N-CEDF was trained for links with {field}={getattr(mspec, field)}, "
                    f"the robot has {field}={getattr(spec, field)}"
                )
        return NCEDFShape(model=model, spec=spec)
    if kind == "spheres":
        if arg:
            n = _parse_count(name, arg)
        else:
            n = DEFAULT_SPHERES_PER_LINK if spheres_per_link is None else int(spheres_per_link)
            if n < 1:
                raise ValueError(f"spheres_per_link must be >= 1, got {n}")
        return SphereShape(spec=spec, per_link=n, name=f"spheres:{n}")
    if kind == "pointcloud":
        if not arg:
            raise ValueError("representation 'pointcloud' needs a point count, e.g. 'pointcloud:1000'")
        total = _parse_count(name, arg)
        per_link = -(-total // spec.n_links)
        return PointCloudShape(coords=_surface_coords(seed, per_link, spec), spec=spec, name=f"pointcloud:{total}")
    raise ValueError(f"unknown representation {name!r}; choose one of {', '.join(REPRESENTATIONS)}")


@functools.partial(jax.jit, static_argnums=(1, 2))
def _surface_coords(seed, per_link: int, spec: RobotSpec):
    """Fixed surface coordinates of a point-cloud shape, (M, per_link, 3); jitted (eagerly,
    the Newton iterations of the sampler compile op by op for every new size)."""
    keys = jax.random.split(jax.random.PRNGKey(seed), spec.n_links)
    return jnp.stack([sample_surface_coords(keys[i], per_link, 0.0, spec.link(i)) for i in range(spec.n_links)])

