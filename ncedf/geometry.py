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

import jax
import jax.numpy as jnp
import numpy as np
import trimesh

from ncedf.robot import (
    RobotSpec,
    _even_series,
    _safe_norm,
    arc_lengths_to_config,
    forward_kinematics,
)


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
    in_plane = _safe_norm(v - h[..., None] * normal)
    return _safe_norm(jnp.stack([h, jnp.maximum(in_plane - radius, 0.0)], axis=-1))


def bending_plane_signed_distance(points: jnp.ndarray, theta: jnp.ndarray, spec: RobotSpec) -> jnp.ndarray:
    """Signed distance to a link whose backbone bends in the xz-plane towards +x.

    Args:
      points: (P, 3) points in the bending-plane frame, m.
      theta: scalar bending angle, rad (0 <= theta < pi).
    Returns:
      (P,) signed distance to the link surface, m; negative inside.
    """
    length, r = spec.length, spec.radius
    kappa = theta / length
    x, y, z = points[..., 0], points[..., 1], points[..., 2]
    # Distance from the backbone circle within the point's meridional plane:
    # R - rho, with R the distance from the torus axis, written without the
    # cancellation of two large numbers when kappa is small.
    axial = jnp.sqrt((1.0 - kappa * x) ** 2 + (kappa * z) ** 2)
    radial = (kappa * (x * x + z * z) - 2.0 * x) / (1.0 + axial)
    to_circle = _safe_norm(jnp.stack([radial, y], axis=-1))

    sinc, versc, cos = _even_series(theta * theta)
    end_centre = jnp.stack([length * theta * versc, 0.0 * theta, length * sinc])
    end_normal = jnp.stack([theta * sinc, 0.0 * theta, cos])
    start_normal = jnp.array([0.0, 0.0, 1.0], dtype=points.dtype)
    to_end = points - end_centre
    in_wedge = (z >= 0.0) & (jnp.sum(to_end * end_normal, axis=-1) <= 0.0)

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


def link_signed_distance(points: jnp.ndarray, theta, phi, spec: RobotSpec) -> jnp.ndarray:
    """Signed distance from link-frame points to one link with (theta, phi).

    Args:
      points: (P, 3) points in the link's base frame, m.
      theta, phi: scalars, rad.
    Returns:
      (P,) signed distance, m (negative inside); ``abs`` of it is the CEDF label.
    """
    return bending_plane_signed_distance(to_bending_plane(points, phi), theta, spec)


def _world_to_link_points(points: jnp.ndarray, arc: jnp.ndarray, spec: RobotSpec) -> jnp.ndarray:
    """Express world points in every link's base frame: (P, 3) -> (M, P, 3)."""
    frames = forward_kinematics(arc, spec)[:-1]
    rot, trans = frames[:, :3, :3], frames[:, :3, 3]
    return jnp.einsum("mji,mpj->mpi", rot, points[None, :, :] - trans[:, None, :])


def robot_link_signed_distances(points: jnp.ndarray, arc: jnp.ndarray, spec: RobotSpec) -> jnp.ndarray:
    """Signed distance from world points to each link of the robot.

    Args:
      points: (P, 3) world points, m.  arc: (M, 3) arc lengths, m.
    Returns:
      (M, P) signed distances, m.
    """
    local = _world_to_link_points(points, arc, spec)
    theta, phi = arc_lengths_to_config(arc, spec)
    return jax.vmap(link_signed_distance, in_axes=(0, 0, 0, None))(local, theta, phi, spec)


def robot_signed_distance(points: jnp.ndarray, arc: jnp.ndarray, spec: RobotSpec) -> jnp.ndarray:
    """Signed distance from world points to the robot (min over links), (P,), m."""
    return jnp.min(robot_link_signed_distances(points, arc, spec), axis=0)


def surface_points_bending_plane(coords: jnp.ndarray, theta, spec: RobotSpec) -> jnp.ndarray:
    """Map surface coordinates to points of a link bent in the xz-plane.

    A surface coordinate ``(u, psi, w)`` names the point
    ``c(u L) + w r (cos psi n(u) + sin psi e_y)``: ``c`` the backbone at arc
    length ``u L``, ``n`` its outward normal in the bending plane. Lateral
    surface points have ``w = 1``; end-disk points have ``u`` in {0, 1}.

    Args:
      coords: (..., 3) surface coordinates.  theta: scalar, rad.
    Returns:
      (..., 3) points in the bending-plane frame, m.
    """
    u, psi, w = coords[..., 0], coords[..., 1], coords[..., 2]
    t = theta * u
    sinc, versc, cos = _even_series(t * t)
    sin = t * sinc
    length, r = spec.length, spec.radius
    radial = w * r * jnp.cos(psi)
    x = length * u * t * versc - radial * cos
    z = length * u * sinc + radial * sin
    y = w * r * jnp.sin(psi)
    return jnp.stack([x, y, z], axis=-1)


def link_surface_points(coords: jnp.ndarray, theta, phi, spec: RobotSpec) -> jnp.ndarray:
    """Surface coordinates (..., 3) -> link-frame points (..., 3) for (theta, phi)."""
    bent = surface_points_bending_plane(coords, theta, spec)
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


def robot_surface_points(coords: jnp.ndarray, arc: jnp.ndarray, spec: RobotSpec) -> jnp.ndarray:
    """Fixed per-link surface coordinates mapped through the kinematics.

    Args:
      coords: (M, P, 3) surface coordinates per link.  arc: (M, 3) arc lengths, m.
    Returns:
      (M, P, 3) world points, m.
    """
    theta, phi = arc_lengths_to_config(arc, spec)
    local = jax.vmap(link_surface_points, in_axes=(0, 0, 0, None))(coords, theta, phi, spec)
    frames = forward_kinematics(arc, spec)[:-1]
    return jnp.einsum("mij,mpj->mpi", frames[:, :3, :3], local) + frames[:, None, :3, 3]


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
    vertices, faces = robot_mesh_arrays(arc, spec, rings, around)
    return trimesh.Trimesh(vertices=vertices, faces=faces, process=False)
