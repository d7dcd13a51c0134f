"""Ground truth: the exact signed distance between the robot and every obstacle of a world.

Independent of the controller's representation. R is the robot body of :mod:`ncedf.geometry`
(per link a tube of radius r around the arc, flat end disks), ``sdf_R`` its exact signed distance
(negative inside). Per obstacle:

* sphere (c, rho): ``sdf_R(c) - rho`` -- exact.
* cloud: ``min_p sdf_R(p)`` over its points -- exact.
* box: :mod:`scenarios.box_distance`, certified within ``box_distance.CERTIFIED``.
* mesh: :mod:`scenarios.mesh_distance`, certified within ``mesh_distance.TOLERANCE``.

Every box and mesh value is a distance between real points (so it is never below the truth
when positive) and comes with a certificate bounding how far above the truth it may be; only a
penetration already certain to be deeper than the tolerance keeps a larger certificate (unless
``exact_depth``). ``DISTANCE_ERROR_BOUND`` adds float32 rounding (about 1e-5 m at 20 m from
the origin) to the boxes' tolerance, the larger of the two.
"""

from __future__ import annotations

import functools
import math

import jax
import jax.numpy as jnp
import numpy as np

from ncedf.geometry import robot_signed_distance
from ncedf.robot import RobotSpec
from scenarios.box_distance import CERTIFIED, box_distances, cell_geometry, exhaustive_box
from scenarios.mesh_distance import mesh_distances
from scenarios.robot_cells import coarse_robot_cells, robot_pose
from scenarios.world import World, WorldError, triangle_wave

DISTANCE_ERROR_BOUND = CERTIFIED + 0.001
# Instants evaluated per call of the batched program (a fixed shape: one compilation per world layout).
_CHUNK = 8
# The judge's time goes in running its batched program, not in compiling it (every substep of every step
# runs the branch and bound): it is compiled at XLA's full optimisation, its default level, even where a
# process lowers the level in XLA_FLAGS as the test session does (conftest.py).
_OPTIMISED = {"xla_backend_optimization_level": 3}


@functools.lru_cache(maxsize=16)
def _arrays(world: World) -> dict:
    """Sphere, box and cloud arrays for the jitted program, built once per world (numpy, float32)."""
    f32 = np.float32
    spheres = np.array([s.centre + s.velocity + (s.radius, s.half_period) for s in world.spheres], np.float64)
    boxes = np.array([b.centre + tuple(0.5 * x for x in b.size) for b in world.boxes]).reshape(-1, 6)
    clouds = [np.asarray(c.points) for c in world.clouds]
    return {
        "spheres": spheres.reshape(-1, 8).astype(f32),
        "boxes": boxes.astype(f32),
        "cloud_points": (np.concatenate(clouds) if clouds else np.zeros((0, 3))).astype(f32),
        "cloud_ids": np.concatenate([np.full(len(c), i) for i, c in enumerate(clouds)]).astype(np.int32)
        if clouds else np.zeros((0,), np.int32),
    }


def _sphere_centres_at(spheres: jnp.ndarray, t) -> jnp.ndarray:
    """(S, 8) rows (centre, velocity, radius, half period) -> (S, 3) centres at time t."""
    return spheres[:, :3] + triangle_wave(jnp.asarray(t), spheres[:, 7])[:, None] * spheres[:, 3:6]


def _distances_one(arc, t, arrays, cells, spec: RobotSpec, n_clouds: int):
    """Sphere, box and cloud distances and certificates at one state and time (each (K,))."""
    values, certs = [], []
    spheres = arrays["spheres"]
    if spheres.shape[0]:
        values.append(robot_signed_distance(_sphere_centres_at(spheres, t), arc, spec) - spheres[:, 6])
        certs.append(jnp.zeros(spheres.shape[0]))
    if arrays["boxes"].shape[0]:
        pose = robot_pose(arc, spec)
        value, cert = box_distances(arc, pose, cell_geometry(cells, pose, spec), arrays["boxes"], cells, spec)
        values.append(value)
        certs.append(cert)
    if n_clouds:
        sdf = robot_signed_distance(arrays["cloud_points"], arc, spec)
        values.append(jax.ops.segment_min(sdf, arrays["cloud_ids"], num_segments=n_clouds))
        certs.append(jnp.zeros(n_clouds))
    return jnp.concatenate(values), jnp.concatenate(certs)


@functools.partial(jax.jit, static_argnums=(4, 5), compiler_options=_OPTIMISED)
def _distances_program(arcs, times, arrays, cells, spec: RobotSpec, n_clouds: int):
    """Batched :func:`_distances_one`: arcs (N, M, 3), times (N,) -> (N, K) values and certificates."""
    return jax.vmap(_distances_one, in_axes=(0, 0, None, None, None, None))(arcs, times, arrays, cells, spec,
                                                                               n_clouds)


@functools.lru_cache(maxsize=None)
def _robot_cells(spec: RobotSpec) -> dict:
    return jax.tree_util.tree_map(jnp.asarray, coarse_robot_cells(spec))


def check_state(arc, spec: RobotSpec) -> np.ndarray:
    """Arc lengths (..., M, 3) as float64, or ValueError naming the problem."""
    arc = np.asarray(arc, dtype=np.float64)
    if arc.shape[-2:] != (spec.n_links, 3):
        raise ValueError(f"arc lengths must have shape (..., {spec.n_links}, 3), got {arc.shape}")
    if not np.all(np.isfinite(arc)):
        raise ValueError("arc lengths contain NaN or inf")
    return arc


def _analytic(world: World, spec: RobotSpec, arcs: np.ndarray, times: np.ndarray, exact_depth: bool):
    """Sphere, box and cloud values and certificates (N, K), boxes refined where uncertified."""
    n = len(arcs)
    arrays = jax.tree_util.tree_map(jnp.asarray, _arrays(world))
    values, certs = [], []
    for start in range(0, n, _CHUNK):
        a, t = arcs[start:start + _CHUNK], times[start:start + _CHUNK]
        pad = _CHUNK - len(a)
        a = np.concatenate([a, np.repeat(a[-1:], pad, axis=0)])
        t = np.concatenate([t, np.repeat(t[-1:], pad)])
        v, c = _distances_program(jnp.asarray(a, jnp.float32), jnp.asarray(t, jnp.float32), arrays,
                                  _robot_cells(spec), spec, len(world.clouds))
        values.append(np.asarray(v, np.float64)[:_CHUNK - pad])
        certs.append(np.asarray(c, np.float64)[:_CHUNK - pad])
    values, certs = np.concatenate(values), np.concatenate(certs)
    # Uncertified (rare): refine without a size limit, unless a penetration deeper than the
    # tolerance is already certain (the value, a real point's, is then an upper bound < -CERTIFIED).
    n_spheres = len(world.spheres)
    for i, k in zip(*np.nonzero((certs > CERTIFIED) & ((values > -CERTIFIED) | exact_depth))):
        values[i, k] = exhaustive_box(arrays["boxes"][k - n_spheres], spec, arcs[i])
        certs[i, k] = CERTIFIED
    return values, certs


def true_distances_certified(world: World, spec: RobotSpec, arcs, times, exact_depth: bool = False):
    """Exact signed distances and their certificates for many states and times at once.

    Args:
      arcs: (N, M, 3) arc lengths, m.  times: (N,) s.
      exact_depth: also refine penetrations deeper than the tolerance until certified (slow;
        by default their value is only certain to be negative and no deeper than the truth).
    Returns:
      values (N, n_obstacles) float64, m (negative = penetration), obstacles in the order
      spheres, boxes, meshes, clouds; certificates (N, n_obstacles): how far above the truth
      each value may be, m.
    """
    if not isinstance(world, World):
        raise WorldError(f"need a World, got {type(world).__name__}")
    arcs = check_state(arcs, spec)
    times = np.asarray(times, dtype=np.float64).reshape(-1)
    if arcs.ndim != 3 or len(times) != len(arcs):
        raise ValueError(f"need arcs (N, M, 3) and times (N,), got {arcs.shape} and {times.shape}")
    n = len(arcs)
    if world.n_obstacles == 0:
        return np.zeros((n, 0)), np.zeros((n, 0))
    columns = [np.zeros((n, 0))] * 2
    if world.spheres or world.boxes or world.clouds:
        columns = _analytic(world, spec, arcs, times, exact_depth)
    meshes = [mesh_distances(mesh, spec, arcs, exact_depth) for mesh in world.meshes]
    cut = len(world.spheres) + len(world.boxes)
    out = []
    for j, part in enumerate(columns):
        middle = [m[j][:, None] for m in meshes]
        out.append(np.concatenate([part[:, :cut], *middle, part[:, cut:]], axis=1))
    return out[0] + 0.0, out[1]  # + 0.0: a contact's -0.0 (its point taken as inside) reads as 0, not "-0.0000"


def true_distances_batch(world: World, spec: RobotSpec, arcs, times, exact_depth: bool = False) -> np.ndarray:
    """The values of :func:`true_distances_certified`, (N, n_obstacles) m."""
    return true_distances_certified(world, spec, arcs, times, exact_depth)[0]


def true_distances(world: World, spec: RobotSpec, arc, t: float) -> np.ndarray:
    """Exact signed distance (n_obstacles,) m between the robot at ``arc`` (M, 3) and each obstacle at time t."""
    return true_distances_batch(world, spec, np.asarray(arc)[None], np.array([t]))[0]


def true_min_distance(world: World, spec: RobotSpec, arc, t: float) -> float:
    """Minimum of :func:`true_distances` (m), +inf without obstacles."""
    d = true_distances(world, spec, arc, t)
    return float(d.min()) if d.size else math.inf
