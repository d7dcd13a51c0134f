"""Piecewise-constant-curvature (PCC) model of a multi-link continuum robot.

Paper Sec. III. A link is an inextensible backbone of length ``L`` actuated by
three chambers at radius ``r``; its state is the three chamber arc lengths.
A robot state is the arc lengths of all links, shape ``(M, 3)`` in metres, each
row summing to ``3 L``.

Everything here is computed from the *bending vector* ``(a, b) = theta (cos phi,
sin phi)``, which is linear in the arc lengths. The link transform and the
forward kinematics are smooth functions of ``(a, b)`` (they depend on ``theta``
only through even functions such as ``sin(theta)/theta``), so values and
gradients are finite at ``theta = 0``, the straight initial state.

Chamber ``j`` (``j = 0, 1, 2``) has arc length
``l_j = L - r theta cos(phi + 2 pi j / 3)``, the inverse of paper eq. (1).
"""

from __future__ import annotations

import dataclasses
import math

import jax.numpy as jnp
import numpy as np

SQRT3 = math.sqrt(3.0)
CHAMBER_ANGLES = (0.0, 2.0 * math.pi / 3.0, 4.0 * math.pi / 3.0)
#: The base's position, m: the world origin (the first frame of :func:`forward_kinematics` is the identity).
BASE = np.zeros(3)
# Below this theta^2 the even functions of theta use their Taylor series.
_SMALL_THETA_SQ = 1e-4


class InvalidStateError(ValueError):
    """A robot state (arc lengths) that violates the robot's limits."""


def _finite(value, name: str) -> float:
    """``value`` as a float, or ValueError naming ``name`` if it is not a finite number."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)) \
            or not math.isfinite(value):
        raise ValueError(f"{name} must be a finite number, got {value!r}")
    return float(value)


@dataclasses.dataclass(frozen=True)
class RobotSpec:
    """Geometry and limits of an ``n_links``-link continuum robot.

    Attributes:
      n_links: number of links M (>= 1).
      length: backbone length L of every link, m.
      radius: link radius r (chambers sit at r; the tube radius), m: one for every link, or a tuple
        of M, one per link from the base (a tapered robot; equal values collapse to one).
      l_min, l_max: chamber arc-length limits, m; ``l_min < L < l_max``.
    """

    n_links: int
    length: float = 2.0
    radius: float | tuple = 0.2
    l_min: float = 1.6
    l_max: float = 2.4

    def __post_init__(self):
        if isinstance(self.n_links, bool) or not isinstance(self.n_links, (int, np.integer)):
            raise ValueError(f"n_links must be an integer, got {self.n_links!r}")
        if self.n_links < 1:
            raise ValueError(f"n_links must be >= 1, got {self.n_links}")
        if isinstance(self.radius, (list, tuple, np.ndarray)):
            radii = tuple(_finite(v, "radius") for v in self.radius)
            if len(radii) != self.n_links:
                raise ValueError(f"{len(radii)} link radii given for a robot of {self.n_links} links")
            object.__setattr__(self, "radius", radii[0] if len(set(radii)) == 1 else radii)
        for name in ("length", "l_min", "l_max") + (() if self.tapered else ("radius",)):
            _finite(getattr(self, name), name)
        if min(self.radii) <= 0:
            raise ValueError(f"radius must be > 0, got {self.radius}")
        if not 0 < self.l_min < self.length < self.l_max:
            raise ValueError(
                f"need 0 < l_min < length < l_max, got l_min={self.l_min}, "
                f"length={self.length}, l_max={self.l_max}"
            )
        thinnest = min(self.radii)
        if thinnest * self.max_bend() >= self.length:
            raise ValueError(
                f"radius {thinnest} m is not below the bend radius {self.length / self.max_bend():.4g} m that "
                f"the arc limits {self.l_min}-{self.l_max} allow a link of length {self.length} (the tube would "
                "fold into itself); narrow the arc limits (the chambers sit at the tube's radius: a thinner tube "
                "bends as tight)"
            )

    @property
    def tapered(self) -> bool:
        """Whether the links have different radii."""
        return isinstance(self.radius, tuple)

    @property
    def radii(self) -> tuple:
        """The radius of each link, (M,) floats, m."""
        return self.radius if self.tapered else (self.radius,) * self.n_links

    @property
    def thickest(self) -> float:
        """The largest link radius, m (what a bound over every link needs)."""
        return max(self.radii)

    def radius_of(self, link=None):
        """Radii that broadcast against per-link arrays, m: the float of a uniform robot; for a
        tapered one ``radii[link]`` (numpy for a numpy index, else jax), or all M for ``link=None``."""
        if not self.tapered:
            return self.radius
        if isinstance(link, np.ndarray):
            return np.asarray(self.radius)[link]
        return jnp.asarray(self.radius) if link is None else jnp.asarray(self.radius)[link]

    def link(self, i: int) -> "RobotSpec":
        """The one-link spec of link ``i`` (0-based from the base)."""
        return dataclasses.replace(self, n_links=1, radius=self.radii[i])

    def link_geometry(self) -> dict:
        """Every field but ``n_links``: what a single link's data, model or hash depends on."""
        return {k: v for k, v in dataclasses.asdict(self).items() if k != "n_links"}

    def max_bend(self) -> float:
        """Largest bending angle theta (rad) the arc-length limits admit (of the thinnest link)."""
        # Chamber j deviates by v_j = r theta cos(phi + 2 pi j / 3) (shortening),
        # with sum_j v_j = 0, -hi <= v_j <= lo and theta^2 = (2/3) sum_j v_j^2 / r^2.
        # This convex function is largest at a vertex of the feasible polygon,
        # where two chambers sit at a limit; keep the feasible vertices.
        lo, hi = self.length - self.l_min, self.l_max - self.length
        vertices = [(lo, lo, -2.0 * lo), (-hi, -hi, 2.0 * hi), (lo, -hi, hi - lo)]
        tol = 1e-12 * (lo + hi)
        best = max(
            sum(v * v for v in vertex)
            for vertex in vertices
            if all(-hi - tol <= v <= lo + tol for v in vertex)
        )
        return math.sqrt(2.0 * best / 3.0) / min(self.radii)

    def scaled(self, factor: float) -> "RobotSpec":
        """The same robot with every length multiplied by ``factor`` (> 0), rounded to 12 digits so that
        scaling there and back returns the same spec."""
        if not factor > 0:
            raise ValueError(f"scale factor must be > 0, got {factor}")

        def scale(v):
            return tuple(scale(x) for x in v) if isinstance(v, tuple) else float(f"{v * factor:.12g}")

        return dataclasses.replace(self, **{k: scale(v) for k, v in self.link_geometry().items()})

    def straight_state(self) -> jnp.ndarray:
        """The straight initial state: every arc length = L, shape (M, 3)."""
        return jnp.full((self.n_links, 3), self.length)


def bending_vector(arc: jnp.ndarray, spec: RobotSpec) -> jnp.ndarray:
    """Bending vector ``theta (cos phi, sin phi)`` of each link, linear in arc.

    Args:
      arc: (..., 3) chamber arc lengths, m.
    Returns:
      (..., 2) array ``(a, b)``; ``theta = |(a, b)|``, ``phi = atan2(b, a)``.
    """
    l1, l2, l3 = arc[..., 0], arc[..., 1], arc[..., 2]
    r = spec.radius_of()  # a tapered robot's (M,) broadcast over the link axis of (..., M, 3)
    a = (l2 + l3 - 2.0 * l1) / (3.0 * r)
    b = (l2 - l3) / (SQRT3 * r)
    return jnp.stack([a, b], axis=-1)


def safe_sqrt(sq: jnp.ndarray) -> jnp.ndarray:
    """``sqrt(max(sq, 0))`` with a zero (not NaN or inf) gradient where ``sq <= 0``."""
    positive = sq > 0
    return jnp.where(positive, jnp.sqrt(jnp.where(positive, sq, 1.0)), 0.0)


def safe_norm(v: jnp.ndarray) -> jnp.ndarray:
    """Euclidean norm over the last axis with a zero (not NaN) gradient at 0."""
    return safe_sqrt(jnp.sum(v * v, axis=-1))


def arc_lengths_to_config(arc: jnp.ndarray, spec: RobotSpec) -> tuple[jnp.ndarray, jnp.ndarray]:
    """Paper eq. (1): arc lengths -> bending angle and bending-plane angle.

    Args:
      arc: (..., 3) chamber arc lengths, m.
    Returns:
      theta (...,) in [0, pi], rad; phi (...,) in [-pi, pi), rad (0 where theta = 0).
    """
    ab = bending_vector(arc, spec)
    theta = safe_norm(ab)
    straight = theta == 0
    a = jnp.where(straight, 1.0, ab[..., 0])
    b = jnp.where(straight, 0.0, ab[..., 1])
    phi = jnp.arctan2(b, a)
    phi = jnp.where(phi >= jnp.pi, phi - 2.0 * jnp.pi, phi)
    return theta, phi


def config_to_arc_lengths(theta: jnp.ndarray, phi: jnp.ndarray, spec: RobotSpec) -> jnp.ndarray:
    """Inverse of paper eq. (1).

    Args:
      theta: (...,) bending angle, rad.  phi: (...,) bending-plane angle, rad.
    Returns:
      (..., 3) arc lengths ``L - r theta cos(phi + 2 pi j / 3)``, m.
    """
    theta = jnp.asarray(theta)
    phi = jnp.asarray(phi)
    angles = jnp.asarray(CHAMBER_ANGLES, dtype=jnp.result_type(phi, float))
    return spec.length - (spec.radius_of() * theta)[..., None] * jnp.cos(phi[..., None] + angles)


def even_series(theta_sq: jnp.ndarray):
    """``sin(t)/t``, ``(1 - cos t)/t^2`` and ``cos t`` as smooth functions of ``t^2``.

    The building blocks of every PCC formula here: a link's transform, backbone
    and surface depend on its bending angle only through these, so values and
    gradients stay finite and exact at ``t = 0`` (Taylor series below
    ``t^2 = 1e-4``).

    Args:
      theta_sq: (...,) squared angle, rad^2.
    Returns:
      sinc, versc, cos: three (...,) arrays.
    """
    small = theta_sq < _SMALL_THETA_SQ
    safe_sq = jnp.where(small, 1.0, theta_sq)
    t = jnp.sqrt(safe_sq)
    sinc = jnp.where(small, 1.0 - theta_sq / 6.0 + theta_sq**2 / 120.0, jnp.sin(t) / t)
    # (1 - cos t) / t^2 = sinc(t / 2)^2 / 2, without the cancellation of 1 - cos t
    half_sinc = jnp.sin(0.5 * t) / (0.5 * t)
    versc = jnp.where(small, 0.5 - theta_sq / 24.0 + theta_sq**2 / 720.0, 0.5 * half_sinc * half_sinc)
    cos = jnp.where(small, 1.0 - theta_sq / 2.0 + theta_sq**2 / 24.0, jnp.cos(t))
    return sinc, versc, cos


def _link_components(ab: jnp.ndarray, length: float):
    """Rotation (3 x 3 nested lists) and translation (3 list) of link transforms.

    The rotation is ``Rz(phi) Ry(theta) Rz(-phi)``: a rotation by theta about
    the axis ``(-sin phi, cos phi, 0)``. The end point is
    ``L ((1 - cos t)/t cos phi, (1 - cos t)/t sin phi, sin t / t)``. Each entry
    is an array of shape (...), so that chaining transforms is element-wise.

    Args:
      ab: (..., 2) bending vector ``theta (cos phi, sin phi)``.
      length: backbone length L, m.
    """
    a, b = ab[..., 0], ab[..., 1]
    sinc, versc, cos = even_series(a * a + b * b)
    # Rodrigues with w = (-b, a, 0): R = I + sinc [w]x + versc [w]x^2.
    r00 = 1.0 - versc * a * a
    r01 = -versc * a * b
    r02 = sinc * a
    r11 = 1.0 - versc * b * b
    r12 = sinc * b
    rot = [[r00, r01, r02], [r01, r11, r12], [-r02, -r12, cos]]
    trans = [length * versc * a, length * versc * b, length * sinc]
    return rot, trans


def _pack(rot, trans) -> jnp.ndarray:
    """Nested per-component rotation and translation -> (..., 4, 4) transforms."""
    zero = jnp.zeros_like(trans[0])
    one = jnp.ones_like(trans[0])
    rows = [[rot[i][0], rot[i][1], rot[i][2], trans[i]] for i in range(3)] + [[zero, zero, zero, one]]
    return jnp.stack([jnp.stack(row, axis=-1) for row in rows], axis=-2)


def link_transform_from_bending(ab: jnp.ndarray, length: float) -> jnp.ndarray:
    """Homogeneous transform from the base to the end of a PCC link.

    Args:
      ab: (..., 2) bending vector ``theta (cos phi, sin phi)``.
      length: backbone length L, m.
    Returns:
      (..., 4, 4) transforms (see ``_link_components``).
    """
    return _pack(*_link_components(ab, length))


def backbone_points(ab: jnp.ndarray, frames: jnp.ndarray, fractions: jnp.ndarray, length: float) -> jnp.ndarray:
    """World points on each link's backbone at the given arc-length fractions.

    The point at arc length ``u L`` is the end of the link's first ``u L`` metres:
    ``L (u^2 versc(u theta) (a, b), u sinc(u theta))`` in the link's base frame
    (:func:`_link_components` with bending vector ``u (a, b)``). In the world it is
    ``o + L u^2 versc R (a, b, 0) + L u sinc R e_z`` for the base frame ``(R, o)``, so
    neither the angle ``phi`` nor a per-point rotation is needed.

    Args:
      ab: (..., M, 2) bending vectors.  frames: (..., M, 4, 4) the links' base frames.
      fractions: (n,) in [0, 1].  length: backbone length L, m.
    Returns:
      (..., M, n, 3) points, m.
    """
    a, b = ab[..., 0:1], ab[..., 1:2]  # (..., M, 1)
    u = jnp.asarray(fractions, ab.dtype)
    sinc, versc, _ = even_series((a * a + b * b) * (u * u))  # (..., M, n)
    across, along = length * u * u * versc, length * u * sinc
    rot, origin = frames[..., :3, :3], frames[..., :3, 3]
    bend = rot[..., 0] * a + rot[..., 1] * b  # R (a, b, 0), (..., M, 3)
    return origin[..., None, :] + across[..., None] * bend[..., None, :] + along[..., None] * rot[..., None, :, 2]


def arc_sagitta(theta: jnp.ndarray, length) -> jnp.ndarray:
    """Largest distance between a circular arc and its chord, m.

    ``rho (1 - cos(theta / 2))`` with ``rho = length / theta``, written as
    ``length theta / 4 * versc(theta / 2)`` so it is smooth at theta = 0.

    Args:
      theta: (...,) arc angle, rad.  length: (...,) or scalar arc length, m.
    """
    _, versc, _ = even_series(theta * theta / 4.0)
    return length * theta / 4.0 * versc


def link_transform(theta: jnp.ndarray, phi: jnp.ndarray, spec: RobotSpec) -> jnp.ndarray:
    """Transform from the base to the end of a link with configuration (theta, phi).

    Args:
      theta: (...,) bending angle, rad.  phi: (...,) bending-plane angle, rad.
    Returns:
      (..., 4, 4) homogeneous transforms (paper: T_i).
    """
    theta = jnp.asarray(theta)
    phi = jnp.asarray(phi)
    ab = jnp.stack([theta * jnp.cos(phi), theta * jnp.sin(phi)], axis=-1)
    return link_transform_from_bending(ab, spec.length)


def forward_kinematics(arc: jnp.ndarray, spec: RobotSpec) -> jnp.ndarray:
    """Forward kinematics (paper eq. 4): the chain of link transforms.

    Computed per component (3 x 3 rotation and translation as separate
    arrays, chained with scalar products) rather than as batched 4 x 4 matrix
    products, which XLA on CPU runs slowly for large batches; the result is
    the same product ``T_1 T_2 ... T_i``.

    Args:
      arc: (..., M, 3) arc lengths, m.
    Returns:
      (..., M + 1, 4, 4): frames[0] is the base (identity), frames[i] the end
      of link i (= base of link i + 1), frames[M] the end-effector pose.
    """
    ab = bending_vector(arc, spec)
    lrot, ltrans = _link_components(ab, spec.length)
    batch = ab.shape[:-2]
    zero = jnp.zeros(batch, ab.dtype)
    one = jnp.ones(batch, ab.dtype)
    rot = [[one if i == j else zero for j in range(3)] for i in range(3)]
    trans = [zero, zero, zero]
    frames = [_pack(rot, trans)]
    for m in range(ab.shape[-2]):
        lr = [[x[..., m] for x in row] for row in lrot]
        lt = [x[..., m] for x in ltrans]
        trans = [rot[i][0] * lt[0] + rot[i][1] * lt[1] + rot[i][2] * lt[2] + trans[i] for i in range(3)]
        rot = [[rot[i][0] * lr[0][j] + rot[i][1] * lr[1][j] + rot[i][2] * lr[2][j] for j in range(3)] for i in range(3)]
        frames.append(_pack(rot, trans))
    return jnp.stack(frames, axis=-3)


def end_effector_pose(arc: jnp.ndarray, spec: RobotSpec) -> jnp.ndarray:
    """End-effector pose T_ee, shape (..., 4, 4), for arc lengths (..., M, 3)."""
    return forward_kinematics(arc, spec)[..., -1, :, :]


def world_to_frame(frames: jnp.ndarray, points: jnp.ndarray) -> jnp.ndarray:
    """World points expressed in frames: ``R^T (p - t)``, broadcasting.

    Written per component: a batched (..., 3, 3) product is slow on CPU.

    Args:
      frames: (..., 4, 4) homogeneous transforms frame -> world.
      points: (..., 3) world points, m (leading axes broadcast with the frames').
    Returns:
      (..., 3) points in the frames, m.
    """
    v = [points[..., j] - frames[..., j, 3] for j in range(3)]
    return jnp.stack([frames[..., 0, i] * v[0] + frames[..., 1, i] * v[1] + frames[..., 2, i] * v[2] for i in range(3)],
                     axis=-1)


def frame_to_world(frames: jnp.ndarray, points: jnp.ndarray) -> jnp.ndarray:
    """Points given in frames, expressed in the world: ``R p + t``, broadcasting (inverse of
    :func:`world_to_frame`; shapes as there)."""
    return jnp.stack(
        [frames[..., i, 0] * points[..., 0] + frames[..., i, 1] * points[..., 1] + frames[..., i, 2] * points[..., 2]
         + frames[..., i, 3] for i in range(3)],
        axis=-1,
    )


def points_in_link_frames(points: jnp.ndarray, frames: jnp.ndarray) -> jnp.ndarray:
    """World points in every link's base frame.

    Args:
      points: (P, 3) world points, m.  frames: (M + 1, 4, 4) forward kinematics.
    Returns:
      (M, P, 3) link-frame points, m.
    """
    return world_to_frame(frames[:-1, None], points[None])


def points_from_link_frames(local: jnp.ndarray, frames: jnp.ndarray) -> jnp.ndarray:
    """Per-link points (M, P, 3) in the links' base frames -> world points (M, P, 3), m."""
    return frame_to_world(frames[:-1, None], local)


# Tolerance of the inextensibility constraint sum(l) = 3L, m: float32 closed
# loops drift by ~1e-5 m over hundreds of steps.
SUM_TOLERANCE = 1e-4


def state_violation(arc: np.ndarray, spec: RobotSpec, atol: float = 1e-6) -> str | None:
    """Why ``arc`` is not a valid state of ``spec``, or None if it is.

    Args:
      arc: (M, 3) arc lengths, m.
      atol: tolerance of the arc-length limits, m (the sums use SUM_TOLERANCE).
    """
    arc = np.asarray(arc, dtype=np.float64)
    if arc.shape != (spec.n_links, 3):
        return f"arc lengths must have shape ({spec.n_links}, 3), got {arc.shape}"
    if not np.all(np.isfinite(arc)):
        return "arc lengths contain NaN or inf"
    low, high = arc.min(), arc.max()
    if low < spec.l_min - atol or high > spec.l_max + atol:
        bad = low if low < spec.l_min - atol else high
        return f"arc length {bad:.6g} outside the limits [{spec.l_min}, {spec.l_max}]"
    sums = arc.sum(axis=1)
    worst = int(np.argmax(np.abs(sums - 3.0 * spec.length)))
    if abs(sums[worst] - 3.0 * spec.length) > SUM_TOLERANCE:
        return (
            f"arc lengths of link {worst + 1} sum to {sums[worst]:.6g}, "
            f"not 3L = {3.0 * spec.length:.6g}"
        )
    return None


def validate_state(arc, spec: RobotSpec) -> np.ndarray:
    """Return ``arc`` as a float array, or raise InvalidStateError saying why not."""
    reason = state_violation(arc, spec)
    if reason is not None:
        raise InvalidStateError(f"invalid robot state: {reason}")
    return np.asarray(arc, dtype=np.float64)


def project_state(arc: jnp.ndarray, spec: RobotSpec) -> jnp.ndarray:
    """The nearest valid state: per link, the Euclidean projection onto
    ``{l : l_1 + l_2 + l_3 = 3 L, l_min <= l_j <= l_max}``.

    A closed loop ``arc + u dt`` in float32 drifts off the sum by ~1e-5 m over
    hundreds of steps; this repairs it (and clips small excursions past the
    limits). The projection is ``clip(l - tau, l_min, l_max)`` with the scalar
    ``tau`` that restores the sum; the sum is piecewise linear and
    non-increasing in ``tau`` with breakpoints ``l_j - l_min`` and
    ``l_j - l_max``, so ``tau`` is found exactly by linear interpolation between
    the two breakpoints that bracket ``3 L`` (no iteration).

    Args:
      arc: (..., 3) arc lengths, m (finite).
    Returns:
      (..., 3) arc lengths within the limits whose rows sum to 3L, m.
    """
    arc = jnp.asarray(arc)
    total = 3.0 * spec.length
    breaks = jnp.sort(jnp.concatenate([arc - spec.l_min, arc - spec.l_max], axis=-1), axis=-1)  # (..., 6)
    sums = jnp.sum(jnp.clip(arc[..., None, :] - breaks[..., :, None], spec.l_min, spec.l_max), axis=-1)  # (..., 6)
    # sums runs from 3 l_max down to 3 l_min; bracket the target between breaks k and k + 1.
    k = jnp.clip(jnp.sum(sums >= total, axis=-1) - 1, 0, 4)[..., None]
    t0, t1 = jnp.take_along_axis(breaks, k, -1), jnp.take_along_axis(breaks, k + 1, -1)
    s0, s1 = jnp.take_along_axis(sums, k, -1), jnp.take_along_axis(sums, k + 1, -1)
    drop = s0 - s1
    tau = jnp.where(drop > 0, t0 + (s0 - total) * (t1 - t0) / jnp.where(drop > 0, drop, 1.0), t0)
    return jnp.clip(arc - tau, spec.l_min, spec.l_max)


def sample_arc_lengths(key, spec: RobotSpec, shape: tuple[int, ...] = ()) -> jnp.ndarray:
    """Random valid link states as in paper Sec. IV-B.

    ``l1`` uniform in the limits, ``l2`` uniform in its admissible range given
    ``l1`` and ``l3 = 3 L - l1 - l2``.

    Args:
      key: jax.random key.
      shape: leading batch shape.
    Returns:
      (*shape, 3) arc lengths, m.
    """
    import jax

    k1, k2 = jax.random.split(key)
    total = 3.0 * spec.length
    l1 = jax.random.uniform(k1, shape, minval=spec.l_min, maxval=spec.l_max)
    lo = jnp.maximum(spec.l_min, total - l1 - spec.l_max)
    hi = jnp.minimum(spec.l_max, total - l1 - spec.l_min)
    l2 = lo + (hi - lo) * jax.random.uniform(k2, shape)
    return jnp.stack([l1, l2, total - l1 - l2], axis=-1)
