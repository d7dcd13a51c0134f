"""Exact geometry of continuum-robot links, in closed form.

A link is the tube of radius r around its circular-arc backbone (length L,
bending angle theta, bending plane phi), closed by flat end disks
perpendicular to the backbone. For theta > 0 it is a wedge of a ring torus
(its axis passes through the centre of curvature, perpendicular to the bending
plane), for theta = 0 a capped cylinder. The formulas below use the curvature
``kappa = theta / L`` and stay exact and finite as ``kappa -> 0``.

Distances are in metres; points are in the frame named by each function.
The unsigned distance to the surface, ``|signed distance|``, is the paper's
CEDF label Gamma_i (paper Sec. IV-A).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import jax
import jax.numpy as jnp
import numpy as np

from ncedf.robot import (
    RobotSpec,
    arc_lengths_to_config,
    bending_vector,
    even_series,
    forward_kinematics,
    points_from_link_frames,
    points_in_link_frames,
    safe_norm,
    safe_sqrt,
)

if TYPE_CHECKING:
    import trimesh

# Below this theta^2 the distance to the backbone circle uses its series form in the
# bending vector (the bending-plane coordinates divide by theta).
_STRAIGHT_THETA_SQ = 1e-6


def to_bending_plane(points: jnp.ndarray, phi: jnp.ndarray) -> jnp.ndarray:
    """Rotate link-frame points by -phi about z so the link bends towards +x.

    Args:
      points: (..., 3) link-frame points, m.  phi: scalar or broadcastable (...,).
    Returns:
      (..., 3) points in the bending-plane frame.
    """
    c, s = jnp.cos(phi), jnp.sin(phi)
    x, y, z = points[..., 0], points[..., 1], points[..., 2]
    return jnp.stack([c * x + s * y, -s * x + c * y, z], axis=-1)


def _disk_distance(v: jnp.ndarray, normal: jnp.ndarray, radius: float) -> jnp.ndarray:
    """Distance from points ``v`` (relative to a disk's centre) to the disk, (...,)."""
    h = jnp.sum(v * normal, axis=-1)
    in_plane = safe_norm(v - h[..., None] * normal)
    return safe_norm(jnp.stack([h, jnp.maximum(in_plane - radius, 0.0)], axis=-1))


def _backbone_circle_distance(points: jnp.ndarray, ab: jnp.ndarray, length: float) -> jnp.ndarray:
    """Distance from link-frame points to the full circle that carries the backbone, (P,).

    In the bending-plane frame (``x' = e . (x, y)``, ``y' = e_perp . (x, y)``,
    ``e = ab / theta``) the circle has radius ``rho = 1 / kappa`` about the
    axis through ``(rho, 0, 0)`` along y'; the distance is
    ``|(R - rho, y')|`` with ``R = sqrt((rho - x')^2 + z^2)``, and
    ``R - rho = (kappa (x'^2 + z^2) - 2 x') / (1 + A)``,
    ``A = kappa R = sqrt((1 - g)^2 + kappa^2 z^2)``, ``g = kappa x' = (a x + b y) / L``.

    Near the straight link (theta^2 < 1e-6) the bending-plane coordinates are
    ill-defined (they divide by theta), so the squared distance is written in
    the bending vector alone: with ``F = (R - rho) + x'``,
    ``F = kappa z^2 H / D^2``, ``x' F = g z^2 H / D^2``,
    ``H = g^2 / (A + 1 - g) + D + g``, ``D = 1 + A``, and
    ``distance^2 = x^2 + y^2 - 2 x' F + F^2`` -- smooth in ``(a, b)`` at 0, so
    the gradient with respect to the arc lengths is right at straight links.

    Args:
      points: (P, 3) link-frame points, m.  ab: (2,) bending vector, rad.  length: L, m.
    """
    x, y, z = points[..., 0], points[..., 1], points[..., 2]
    a, b = ab[..., 0], ab[..., 1]
    theta_sq = a * a + b * b
    kappa_sq = theta_sq / (length * length)
    g = (a * x + b * y) / length
    axial = jnp.sqrt((1.0 - g) ** 2 + kappa_sq * z * z)
    near = theta_sq < _STRAIGHT_THETA_SQ
    # bent: bending-plane coordinates
    theta = jnp.sqrt(jnp.where(near, 1.0, theta_sq))
    xp, yp = (a * x + b * y) / theta, (a * y - b * x) / theta
    radial = (theta / length * (xp * xp + z * z) - 2.0 * xp) / (1.0 + axial)
    bent_sq = radial * radial + yp * yp
    # near straight: the series-free form in (a, b)
    d = 1.0 + axial
    h = g * g / jnp.where(near, axial + 1.0 - g, 1.0) + d + g
    z2h = z * z * h / (d * d)
    near_sq = x * x + y * y - 2.0 * g * z2h + kappa_sq * z2h * z2h
    return safe_sqrt(jnp.where(near, near_sq, bent_sq))


def link_signed_distance_ab(points: jnp.ndarray, ab: jnp.ndarray, spec: RobotSpec, radius=None) -> jnp.ndarray:
    """Signed distance from link-frame points to the link with bending vector ``ab``.

    The body is the tube of radius r around the backbone arc, closed by flat
    end disks: inside the wedge between the two end planes the distance is
    that to the backbone circle minus r; outside it, the distance to the
    nearer end disk. Every quantity is a smooth function of ``ab`` (end point
    and normal through :func:`ncedf.robot.even_series`), so the distance is
    differentiable in the arc lengths at straight links too.

    Args:
      points: (P, 3) points in the link's base frame, m.
      ab: (2,) bending vector ``theta (cos phi, sin phi)``, rad (theta < pi).
      radius: the link's radius, m (default ``spec.radius``; a link of a tapered robot).
    Returns:
      (P,) signed distance to the link surface, m; negative inside.
    """
    length, r = spec.length, spec.radius if radius is None else radius
    to_circle = _backbone_circle_distance(points, ab, length)
    a, b = ab[..., 0], ab[..., 1]
    sinc, versc, cos = even_series(a * a + b * b)
    end_centre = jnp.stack([length * versc * a, length * versc * b, length * sinc])
    end_normal = jnp.stack([sinc * a, sinc * b, cos])
    start_normal = jnp.array([0.0, 0.0, 1.0], dtype=points.dtype)
    to_end = points - end_centre
    in_wedge = (points[..., 2] >= 0.0) & (jnp.sum(to_end * end_normal, axis=-1) <= 0.0)

    caps = jnp.minimum(
        _disk_distance(points, start_normal, r),
        _disk_distance(to_end, end_normal, r),
    )
    inside = in_wedge & (to_circle <= r)
    return jnp.where(
        inside,
        -jnp.minimum(r - to_circle, caps),
        jnp.where(in_wedge, to_circle - r, caps),
    )


def link_signed_distance(points: jnp.ndarray, theta, phi, spec: RobotSpec, radius=None) -> jnp.ndarray:
    """Signed distance from link-frame points to one link with (theta, phi).

    Args:
      points: (P, 3) points in the link's base frame, m.
      theta, phi: scalars, rad.  radius: as in :func:`link_signed_distance_ab`.
    Returns:
      (P,) signed distance, m (negative inside); ``abs`` of it is the CEDF label.
    """
    ab = jnp.stack([theta * jnp.cos(phi), theta * jnp.sin(phi)])
    return link_signed_distance_ab(points, ab, spec, radius)


def robot_link_signed_distances(points: jnp.ndarray, arc: jnp.ndarray, spec: RobotSpec) -> jnp.ndarray:
    """Signed distance from world points to each link of the robot.

    Computed from the bending vectors, so values and gradients (with respect to
    the points and the arc lengths) are smooth at straight links.

    Args:
      points: (P, 3) world points, m.  arc: (M, 3) arc lengths, m.
    Returns:
      (M, P) signed distances, m.
    """
    local = points_in_link_frames(points, forward_kinematics(arc, spec))
    return jax.vmap(link_signed_distance_ab, in_axes=(0, 0, None, 0 if spec.tapered else None))(
        local, bending_vector(arc, spec), spec, spec.radius_of())


def robot_signed_distance(points: jnp.ndarray, arc: jnp.ndarray, spec: RobotSpec) -> jnp.ndarray:
    """Signed distance from world points to the robot (min over links), (P,), m."""
    return jnp.min(robot_link_signed_distances(points, arc, spec), axis=0)


def surface_points_bending_plane(coords: jnp.ndarray, theta, spec: RobotSpec, radius=None) -> jnp.ndarray:
    """Map surface coordinates to points of a link bent in the xz-plane.

    A surface coordinate ``(u, psi, w)`` names the point
    ``c(u L) + w r (cos psi n(u) + sin psi e_y)``: ``c`` the backbone at arc
    length ``u L``, ``n`` its outward normal in the bending plane. Lateral
    surface points have ``w = 1``; end-disk points have ``u`` in {0, 1}.

    Args:
      coords: (..., 3) surface coordinates.  theta: scalar, rad.
      radius: the link's radius, m, scalar or (...,) (default ``spec.radius``).
    Returns:
      (..., 3) points in the bending-plane frame, m.
    """
    u, psi, w = coords[..., 0], coords[..., 1], coords[..., 2]
    t = theta * u
    sinc, versc, cos = even_series(t * t)
    sin = t * sinc
    length, r = spec.length, spec.radius if radius is None else radius
    radial = w * r * jnp.cos(psi)
    x = length * u * t * versc - radial * cos
    z = length * u * sinc + radial * sin
    y = w * r * jnp.sin(psi)
    return jnp.stack([x, y, z], axis=-1)


def link_surface_points(coords: jnp.ndarray, theta, phi, spec: RobotSpec, radius=None) -> jnp.ndarray:
    """Surface coordinates (..., 3) -> link-frame points (..., 3) for (theta, phi); ``radius`` as in
    :func:`surface_points_bending_plane`."""
    bent = surface_points_bending_plane(coords, theta, spec, radius)
    return to_bending_plane(bent, -phi)


def sample_surface_coords(key, n: int, theta, spec: RobotSpec) -> jnp.ndarray:
    """Surface coordinates distributed uniformly by area on a link with bend theta.

    The lateral area element is ``r (1 + kappa r cos psi) ds dpsi`` (total
    ``2 pi r L``); each end disk has area ``pi r^2``.

    Args:
      key: jax.random key.  n: number of points.  theta: scalar, rad.
    Returns:
      (n, 3) coordinates ``(u, psi, w)`` for ``surface_points_bending_plane``.
    """
    r, length = spec.radius, spec.length
    k_part, k_u, k_psi, k_w = jax.random.split(key, 4)
    lateral_area = 2.0 * jnp.pi * r * length
    cap_area = jnp.pi * r * r
    part = jax.random.choice(
        k_part, 3, (n,), p=jnp.array([lateral_area, cap_area, cap_area]) / (lateral_area + 2 * cap_area)
    )
    u = jax.random.uniform(k_u, (n,))
    target = 2.0 * jnp.pi * jax.random.uniform(k_psi, (n,))
    # Invert the CDF (psi + a sin psi) / 2 pi of the lateral density by Newton.
    a = theta / length * r
    psi = target
    for _ in range(8):
        psi = psi - (psi + a * jnp.sin(psi) - target) / (1.0 + a * jnp.cos(psi))
    w_cap = jnp.sqrt(jax.random.uniform(k_w, (n,)))
    lateral = part == 0
    u = jnp.where(lateral, u, jnp.where(part == 1, 0.0, 1.0))
    psi = jnp.where(lateral, psi, target)
    w = jnp.where(lateral, 1.0, w_cap)
    return jnp.stack([u, psi, w], axis=-1)


def sample_link_surface(key, n: int, theta, phi, spec: RobotSpec) -> jnp.ndarray:
    """``n`` points uniformly by area on the surface of a link, link frame, (n, 3) m."""
    return link_surface_points(sample_surface_coords(key, n, theta, spec), theta, phi, spec)


def robot_surface_points(coords: jnp.ndarray, arc: jnp.ndarray, spec: RobotSpec, frames=None) -> jnp.ndarray:
    """Fixed per-link surface coordinates mapped through the kinematics.

    Args:
      coords: (M, P, 3) surface coordinates per link.  arc: (M, 3) arc lengths, m.
      frames: (M + 1, 4, 4) forward kinematics of ``arc`` if already computed.
    Returns:
      (M, P, 3) world points, m.
    """
    theta, phi = arc_lengths_to_config(arc, spec)
    local = jax.vmap(link_surface_points, in_axes=(0, 0, 0, None, 0 if spec.tapered else None))(
        coords, theta, phi, spec, spec.radius_of())
    return points_from_link_frames(local, forward_kinematics(arc, spec) if frames is None else frames)


def mesh_grid_coords(rings: int, around: int) -> np.ndarray:
    """Surface coordinates of a link mesh's vertices, (rings * around + 2, 3).

    ``rings`` cross-sections of ``around`` vertices each, then the two disk
    centres (start, end).
    """
    u, psi = np.meshgrid(np.linspace(0.0, 1.0, rings), np.arange(around) * 2 * np.pi / around, indexing="ij")
    lateral = np.stack([u.ravel(), psi.ravel(), np.ones(u.size)], axis=-1)
    centres = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    return np.concatenate([lateral, centres], axis=0)


def mesh_grid_faces(rings: int, around: int) -> np.ndarray:
    """Outward-oriented triangles of one closed link tube, (F, 3) int32."""
    idx = np.arange(rings * around).reshape(rings, around)
    nxt = np.roll(idx, -1, axis=1)
    a, b, c, d = idx[:-1], nxt[:-1], idx[1:], nxt[1:]
    side = np.concatenate(
        [np.stack([a, c, b], -1).reshape(-1, 3), np.stack([b, c, d], -1).reshape(-1, 3)]
    )
    start, end = rings * around, rings * around + 1
    cap0 = np.stack([np.full(around, start), idx[0], nxt[0]], -1)
    cap1 = np.stack([np.full(around, end), nxt[-1], idx[-1]], -1)
    return np.concatenate([side, cap0, cap1]).astype(np.int32)


_robot_surface_points_jit = jax.jit(robot_surface_points, static_argnums=2)


def robot_mesh_arrays(arc: jnp.ndarray, spec: RobotSpec, rings: int = 24, around: int = 24):
    """Vertices (M * V, 3) and faces (M * F, 3) of the robot's closed link tubes."""
    coords = np.broadcast_to(mesh_grid_coords(rings, around), (spec.n_links, rings * around + 2, 3))
    vertices = np.asarray(_robot_surface_points_jit(jnp.asarray(coords), jnp.asarray(arc), spec))
    faces = mesh_grid_faces(rings, around)
    per_link = rings * around + 2
    all_faces = faces[None] + per_link * np.arange(spec.n_links)[:, None, None]
    return vertices.reshape(-1, 3), all_faces.reshape(-1, 3)


def robot_mesh(arc, spec: RobotSpec, rings: int = 24, around: int = 24) -> trimesh.Trimesh:
    """The robot's surface as a trimesh: one closed tube per link (not merged)."""
    import trimesh  # here: the package's only use of trimesh, and slow to import
    vertices, faces = robot_mesh_arrays(arc, spec, rings, around)
    return trimesh.Trimesh(vertices=vertices, faces=faces, process=False)
