"""Cells of the robot's surface coordinates, the unit of the judge's branch and bounds.

A surface coordinate ``(u, psi, w)`` (:func:`ncedf.geometry.surface_points_bending_plane`) names a
point of a link: lateral cells vary (u, psi) at w = 1, the base and tip disk cells (w, psi) at
u = 0 or 1. A cell is its centre and half extents along (A, psi), A = u on lateral cells and w on
disks. Every point of a cell is joined to its centre by a path on the surface no longer than its
path radius (:func:`path_radius`), so a 1-Lipschitz function changes by at most that over it.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from ncedf.compile_cache import bucket
from ncedf.geometry import link_surface_points
from ncedf.robot import RobotSpec, arc_lengths_to_config, forward_kinematics, frame_to_world

# Coarse grid per link (lateral u x psi) and on the base and tip disks (w x psi).
_LATERAL_CELLS = (12, 8)
_DISK_CELLS = (2, 8)


def coarse_robot_cells(spec: RobotSpec) -> dict:
    """The coarse cells of the robot surface (numpy): lateral cells of every link, base and tip disks.

    Returns a dict of arrays over cells: coords (C, 3) centre (u, psi, w), half (C, 2)
    half extents along (A, psi) with A = u on lateral cells and w on disks, link (C,) and disk (C,).
    """
    n_u, n_psi = _LATERAL_CELLS
    n_w, n_psi_d = _DISK_CELLS
    u = (np.arange(n_u) + 0.5) / n_u
    psi = (np.arange(n_psi) + 0.5) * 2.0 * np.pi / n_psi
    uu, pp = np.meshgrid(u, psi, indexing="ij")
    lateral = np.stack([uu.ravel(), pp.ravel(), np.ones(uu.size)], -1)
    m = spec.n_links
    w = (np.arange(n_w) + 0.5) / n_w
    psi_d = (np.arange(n_psi_d) + 0.5) * 2.0 * np.pi / n_psi_d
    ww, pd = np.meshgrid(w, psi_d, indexing="ij")
    disk = np.stack([np.zeros(ww.size), pd.ravel(), ww.ravel()], -1)
    tip = disk + np.array([1.0, 0.0, 0.0])
    coords = np.concatenate([np.tile(lateral, (m, 1)), disk, tip])
    n_lat, n_disk = len(lateral), len(disk)
    half = np.concatenate([np.tile([0.5 / n_u, np.pi / n_psi], (m * n_lat, 1)),
                           np.tile([0.5 / n_w, np.pi / n_psi_d], (2 * n_disk, 1))])
    link = np.concatenate([np.repeat(np.arange(m), n_lat), np.zeros(n_disk, int), np.full(n_disk, m - 1)])
    is_disk = np.concatenate([np.zeros(m * n_lat, bool), np.ones(2 * n_disk, bool)])
    return {"coords": coords.astype(np.float32), "half": half.astype(np.float32),
            "link": link.astype(np.int32), "disk": is_disk}


def robot_pose(arc: jnp.ndarray, spec: RobotSpec) -> dict:
    """What the surface cells need of a state: frames (M + 1, 4, 4), theta (M,), phi (M,)."""
    theta, phi = arc_lengths_to_config(arc, spec)
    return {"frames": forward_kinematics(arc, spec), "theta": theta, "phi": phi}


def path_radius(half: np.ndarray, coords: np.ndarray, disk: np.ndarray, theta: np.ndarray, link: np.ndarray,
                spec: RobotSpec) -> np.ndarray:
    """Path radius (C,) m of cells with half extents (C, 2), centres (C, 3) on links (C,) bent by theta (C,).

    Lateral: ``|p_u| <= L + theta r``, ``|p_psi| = r``; disks: ``|p_w| = r``, ``|p_psi| = w r``.
    """
    da, db = half[:, 0], half[:, 1]
    r = spec.radius_of(link)
    lateral = (spec.length + theta * r) * da + r * db
    return np.where(disk, r * da + r * (coords[:, 2] + da) * db, lateral)


@functools.partial(jax.jit, static_argnums=(3,))
def _cell_points_program(pose: dict, which: dict, coords: jnp.ndarray, spec: RobotSpec):
    frames = pose["frames"][which["instant"], which["link"]]
    theta = pose["theta"][which["instant"], which["link"]]
    phi = pose["phi"][which["instant"], which["link"]]

    def world(c):
        return frame_to_world(frames, link_surface_points(c, theta, phi, spec, spec.radius_of(which["link"])))

    axis = coords * jnp.array([1.0, 0.0, 0.0], coords.dtype)
    backbone, tangent = jax.jvp(world, (axis,), (jnp.broadcast_to(jnp.array([1.0, 0.0, 0.0], coords.dtype),
                                                                  coords.shape),))
    tangent = tangent / jnp.linalg.norm(tangent, axis=-1, keepdims=True)
    return jnp.concatenate([world(coords), backbone, tangent, theta[:, None]], axis=1)


@functools.partial(jax.jit, static_argnums=(1,))
def _poses_program(arcs: jnp.ndarray, spec: RobotSpec) -> dict:
    return jax.vmap(robot_pose, in_axes=(0, None))(arcs, spec)


def poses(arcs: np.ndarray, spec: RobotSpec) -> dict:
    """Poses of N states (N, M, 3) m, padded to a bucket (numpy leaves, first axis >= N)."""
    n = len(arcs)
    padded = np.concatenate([arcs, np.repeat(arcs[-1:], bucket(n, 8) - n, axis=0)])
    return jax.device_get(_poses_program(jnp.asarray(padded, jnp.float32), spec))


def cell_points(pose: dict, instant: np.ndarray, link: np.ndarray, coords: np.ndarray, spec: RobotSpec):
    """World geometry of C cells of the states in ``pose``, float64 numpy.

    Returns:
      centre (C, 3) the cell centre's point; backbone (C, 3) the backbone point at the centre's u
      (a disk's centre); tangent (C, 3) the unit backbone tangent there (a disk's normal); theta (C,).
    """
    n = len(coords)
    size = bucket(n)
    pad = size - n
    which = {"instant": np.concatenate([instant, np.zeros(pad, np.int32)]),
             "link": np.concatenate([link, np.zeros(pad, np.int32)])}
    padded = np.concatenate([coords, np.zeros((pad, 3), coords.dtype)]).astype(np.float32)
    out = np.asarray(_cell_points_program(pose, which, padded, spec), np.float64)[:n]
    return out[:, 0:3], out[:, 3:6], out[:, 6:9], out[:, 9]
