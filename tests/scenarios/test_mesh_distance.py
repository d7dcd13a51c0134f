"""The robot-to-mesh distance against dense brute force (scenarios.mesh_distance).

Truths built here: the robot surface sampled every 2 mm or finer with trimesh's closest points
(the distance when disjoint), the mesh subdivided to 2 mm with the robot's closed-form signed
distance (contact and penetration), and trimesh's containment (a robot inside a closed mesh).
The robot is a small two-link one (L = 0.2 m, r = 2 cm), so that 1 mm is a real test.
"""

from __future__ import annotations

import math
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import trimesh

from ncedf.geometry import robot_signed_distance, robot_surface_points
from ncedf.robot import RobotSpec, forward_kinematics, sample_arc_lengths
from scenarios.judge import judge_step
from scenarios import mesh_distance
from scenarios.mesh_check import MeshWarning
from scenarios.truth import true_distances_certified
from scenarios.world import MeshObstacle, World

SPEC = RobotSpec(2, length=0.2, radius=0.02, l_min=0.16, l_max=0.24)
SPACING = 0.002
CERTIFIED = 0.001


def dense_surface(arc) -> tuple[np.ndarray, float]:
    """Robot surface points (lateral, base and tip disks) at most SPACING apart, and their covering radius."""
    n_u = int(np.ceil(SPEC.length * 1.3 / SPACING)) + 1
    n_psi = int(np.ceil(2 * np.pi * SPEC.radius / SPACING))
    u, psi = np.linspace(0, 1, n_u), np.linspace(0, 2 * np.pi, n_psi, endpoint=False)
    uu, pp = np.meshgrid(u, psi, indexing="ij")
    lateral = np.stack([uu.ravel(), pp.ravel(), np.ones(uu.size)], -1)
    ww, pd = np.meshgrid(np.linspace(0, 1, int(SPEC.radius / SPACING) + 1), psi, indexing="ij")
    disk = np.stack([np.zeros(ww.size), pd.ravel(), ww.ravel()], -1)
    points = jax.jit(robot_surface_points, static_argnums=2)
    m = SPEC.n_links
    lat = np.asarray(points(jnp.asarray(np.broadcast_to(lateral, (m,) + lateral.shape)), arc, SPEC)).reshape(-1, 3)
    base = np.asarray(points(jnp.asarray(np.broadcast_to(disk, (m,) + disk.shape)), arc, SPEC))[0]
    tip = np.asarray(points(jnp.asarray(np.broadcast_to(disk + [1, 0, 0], (m,) + disk.shape)), arc, SPEC))[-1]
    return np.concatenate([lat, base, tip]).astype(np.float64), SPACING


def robot_sdf(points, arc) -> np.ndarray:
    return np.asarray(jax.jit(robot_signed_distance, static_argnums=2)(jnp.asarray(points, jnp.float32), arc, SPEC),
                      np.float64)


def nearest(mesh: trimesh.Trimesh, points: np.ndarray) -> np.ndarray:
    """Distances (P,) from points to the mesh by trimesh, inf where a point cannot be the nearest:
    its distance to the mesh's box exceeds an exact distance of every 25th point."""
    _, some, _ = trimesh.proximity.closest_point(mesh, points[::25])
    to_box = np.linalg.norm(np.maximum(np.maximum(mesh.bounds[0] - points, points - mesh.bounds[1]), 0), axis=1)
    out = np.full(len(points), np.inf)
    near = to_box <= some.min()
    out[near] = trimesh.proximity.closest_point(mesh, points[near])[1]
    return out


def brute_force(mesh: trimesh.Trimesh, arc) -> tuple[float, float]:
    """Bounds (low, high) on the truth of scenarios.mesh_distance from dense samples of both sides."""
    surface, cover = dense_surface(arc)
    # the mesh near the robot's box (a point with sdf_R < 0 lies in it), subdivided to SPACING
    low, high = surface.min(axis=0) - 0.01, surface.max(axis=0) + 0.01
    tri = mesh.triangles
    near = np.all((tri.min(axis=1) <= high) & (tri.max(axis=1) >= low), axis=1)
    on_mesh = np.inf
    if near.any():
        fine, _ = trimesh.remesh.subdivide_to_size(mesh.vertices, mesh.faces[near], max_edge=SPACING)
        on_mesh = robot_sdf(fine, arc).min()  # real mesh points: >= the truth
    if on_mesh < 0:  # the surface enters the body: the truth is min sdf_R over the mesh
        return on_mesh - SPACING, on_mesh
    to_mesh = nearest(mesh, surface)
    disjoint = min(to_mesh.min(), on_mesh)
    if mesh.is_watertight and mesh.contains(surface[:1])[0]:  # clear of the surface, inside the solid
        return -disjoint, -(to_mesh.min() - cover)
    return disjoint - cover, disjoint


def judged(mesh: trimesh.Trimesh, arc) -> tuple[float, float]:
    values, certificates = true_distances_certified(World(meshes=(MeshObstacle(mesh.vertices, mesh.faces),)), SPEC,
                                                    np.asarray(arc)[None], np.zeros(1))
    return float(values[0, 0]), float(certificates[0, 0])


def robot_point(arc, link: int, u: float) -> tuple[np.ndarray, np.ndarray]:
    """A backbone point of ``link`` at fraction ``u`` and a unit direction normal to the backbone there."""
    coords = jnp.asarray(np.broadcast_to([[u, 0.0, 0.0], [u, 0.0, 1.0]], (SPEC.n_links, 2, 3)))
    centre, side = np.asarray(jax.jit(robot_surface_points, static_argnums=2)(coords, arc, SPEC))[link]
    return centre, (side - centre) / np.linalg.norm(side - centre)


@pytest.fixture(scope="module")
def arcs():
    return np.asarray(sample_arc_lengths(jax.random.PRNGKey(3), SPEC, (4, SPEC.n_links)), np.float64)


def sphere_at(centre, radius, subdivisions=3) -> trimesh.Trimesh:
    return trimesh.creation.icosphere(subdivisions=subdivisions, radius=radius).apply_translation(centre)


def beside(arc, link, u, gap, shape: trimesh.Trimesh) -> trimesh.Trimesh:
    """``shape`` moved along the robot's normal at (link, u) until its vertices are ``gap`` from the robot."""
    centre, normal = robot_point(arc, link, u)
    shape = shape.copy()
    shape.apply_translation(centre + normal * (SPEC.radius + 0.3) - shape.bounds.mean(axis=0))
    for _ in range(6):
        shape.apply_translation(normal * (gap - robot_sdf(shape.vertices, arc).min()))
    return shape


def check(mesh, arc):
    low, high = brute_force(mesh, arc)
    value, certificate = judged(mesh, arc)
    # the value is never below the truth, and its certificate brackets it: within 1 mm but for
    # penetrations already certain to be deeper than that
    assert low - 1e-5 <= value and value - certificate <= high + 1e-5, (low, value, certificate, high)
    assert certificate <= CERTIFIED + 1e-6 or value < -CERTIFIED
    return value


@pytest.mark.parametrize("gap", [0.003, 0.05, 0.0, -0.01])
def test_closed_sphere_mesh_near_far_touching_and_in(arcs, gap):
    mesh = beside(arcs[0], 1, 0.5, gap, sphere_at((0, 0, 0), 0.05))
    value = check(mesh, arcs[0])
    assert (value < 0) == (gap < 0) if gap else abs(value) <= CERTIFIED


def test_open_concave_wavy_plate(arcs):
    x, y = np.meshgrid(np.linspace(-0.15, 0.15, 31), np.linspace(-0.15, 0.15, 31), indexing="ij")
    z = 0.02 * np.sin(20 * x) * np.cos(15 * y)
    grid = np.arange(31 * 31).reshape(31, 31)
    quads = np.stack([grid[:-1, :-1], grid[1:, :-1], grid[1:, 1:], grid[:-1, 1:]], -1).reshape(-1, 4)
    faces = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    plate = trimesh.Trimesh(np.stack([x.ravel(), y.ravel(), z.ravel()], -1), faces, process=False)
    for arc, gap in zip(arcs[1:3], (0.004, -0.005)):
        with pytest.warns(MeshWarning, match="open"):
            value = check(beside(arc, 0, 0.7, gap, plate), arc)
        assert (value < 0) == (gap < 0)


def test_thin_wall_and_a_torus_around_the_robot(arcs):
    wall = trimesh.creation.box(extents=(0.3, 0.3, 0.002))
    check(beside(arcs[1], 1, 0.9, 0.002, wall), arcs[1])
    torus = trimesh.creation.torus(0.05, 0.01, major_sections=48, minor_sections=12)
    centre, normal = robot_point(arcs[2], 0, 0.5)
    torus.apply_translation(centre + normal * 0.005)  # the link passes through the hole, off its centre
    check(torus, arcs[2])


def test_a_mesh_touching_the_robot_at_one_point(arcs):
    tip = trimesh.Trimesh([[0, 0, 0], [0.1, 0.02, 0.03], [0.1, -0.03, 0.02], [0.1, 0.0, -0.04]],
                          [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    centre, normal = robot_point(arcs[3], 1, 0.3)
    touch = centre + normal * SPEC.radius  # the tetrahedron's apex on the surface, its body outward
    rotation = trimesh.geometry.align_vectors([1, 0, 0], normal)
    tip.apply_transform(rotation)
    tip.apply_translation(touch)
    value = check(tip, arcs[3])
    assert abs(value) <= CERTIFIED


@pytest.mark.parametrize("closed", [True, False])
def test_a_mesh_wholly_inside_the_robot_is_a_collision(arcs, closed):
    centre, normal = robot_point(arcs[0], 0, 0.4)
    ball = sphere_at(centre + normal * 0.005, 0.008, subdivisions=2)
    if not closed:
        ball = trimesh.Trimesh(ball.vertices, ball.faces[:-6], process=False)
        with pytest.warns(MeshWarning):
            value = check(ball, arcs[0])
    else:
        value = check(ball, arcs[0])
    assert value < 0


def test_the_robot_wholly_inside_a_closed_mesh_is_a_collision(arcs):
    frames = np.asarray(forward_kinematics(jnp.asarray(arcs[1]), SPEC))
    room = sphere_at(frames[1, :3, 3], 0.6, subdivisions=2)
    # the room is convex: from inside, the distance to its surface is the least of its face planes' (closed form)
    surface, cover = dense_surface(arcs[1])
    depth = np.min(np.einsum("fk,fk->f", room.face_normals, room.triangles[:, 0])[None]
                   - surface @ room.face_normals.T, axis=1)
    assert depth.min() > 0 and room.contains(surface[:1])[0]
    value, certificate = judged(room, arcs[1])
    # the truth is -dist(R, T), in [-depth.min(), -(depth.min() - cover)]; the value never below it
    assert -depth.min() - 1e-5 <= value and value - certificate <= -(depth.min() - cover) + 1e-5
    assert value < 0 and certificate <= CERTIFIED


def test_the_robot_inside_one_of_two_boxes_sharing_a_face_is_a_collision(arcs):
    """Two closed boxes written as one mesh, their shared face's corners merged (its edges in four
    faces): still a solid, so a robot inside one of them, clear of every face, collides."""
    frames = np.asarray(forward_kinematics(jnp.asarray(arcs[1]), SPEC))
    centre = frames[1, :3, 3]
    room = trimesh.creation.box(bounds=[centre - 0.4, centre + 0.4])
    annex = trimesh.creation.box(bounds=[centre + (0.4, -0.4, -0.4), centre + (0.9, 0.4, 0.4)])
    both = trimesh.util.concatenate([room, annex])
    surface, cover = dense_surface(arcs[1])
    # the annex lies beyond the room's face x = 0.4, so the room's face planes are the nearest (closed form)
    depth = np.min(0.4 - np.abs(surface - centre), axis=1)
    assert depth.min() > 0
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        value, certificate = judged(both, arcs[1])
    assert -depth.min() - 1e-5 <= value and value - certificate <= -(depth.min() - cover) + 1e-5
    assert value < 0 and certificate <= CERTIFIED


def test_the_judge_reports_the_certificate_and_sees_the_mesh(arcs):
    mesh = beside(arcs[0], 1, 0.5, 0.01, sphere_at((0, 0, 0), 0.05))
    world = World(meshes=(MeshObstacle(mesh.vertices, mesh.faces),))
    step = judge_step(world, SPEC, arcs[0], arcs[0], 0.0, 0.05)
    assert step.first_collision_time is None
    assert 0.0 <= step.certificate <= CERTIFIED
    assert abs(step.min_distance - 0.01) <= 0.002


def blob(rng) -> trimesh.Trimesh:
    """A closed, non-convex mesh: an icosphere of radius 4 cm with its vertices pushed in and out."""
    ball = trimesh.creation.icosphere(subdivisions=2, radius=0.04)
    bumps = 1.0 + 0.35 * np.sin(3.0 * ball.vertices @ rng.normal(size=3) / 0.04 + rng.uniform(0, 6))
    return trimesh.Trimesh(ball.vertices * bumps[:, None], ball.faces)


def test_random_non_convex_meshes_at_random_gaps(arcs):
    rng = np.random.default_rng(8)
    for arc in arcs:
        gap = rng.uniform(-0.005, 0.03)
        shape = blob(rng)
        value = check(beside(arc, int(rng.integers(SPEC.n_links)), rng.uniform(0.1, 0.9), gap, shape), arc)
        assert (value < 0) == (gap < -CERTIFIED) or abs(gap) <= CERTIFIED


@pytest.mark.parametrize("gap", [0.003, 0.0])
def test_a_robot_standing_on_a_plate_its_base_disk_bounded_once_for_every_state(arcs, gap, monkeypatch):
    """A plate 3 mm under the base, or touching it (the base disk parallel to its top: ties over the
    whole disk; a state bent into it too): every state's value within its certificate of brute force,
    the base disk's bound found once for them all and kept with the mesh."""
    plate = trimesh.creation.box(extents=(0.3, 0.3, 0.004)).apply_translation((0.05, 0.0, -0.002 - gap))
    obstacle = MeshObstacle(plate.vertices, plate.faces)
    found, disk_bound = [], mesh_distance._disk_bound
    monkeypatch.setattr(mesh_distance, "_disk_bound", lambda *args: found.append(args) or disk_bound(*args))
    values, certificates = true_distances_certified(World(meshes=(obstacle,)), SPEC, arcs, np.zeros(len(arcs)))
    assert len(found) == 1 and found[0][0] is obstacle
    assert list(mesh_distance._DISK_BOUNDS[obstacle]) == [SPEC]
    for arc, value, certificate in zip(arcs, values[:, 0], certificates[:, 0]):
        low, high = brute_force(plate, arc)
        assert low - 1e-5 <= value and value - certificate <= high + 1e-5, (low, value, certificate, high)
        assert (certificate <= CERTIFIED + 1e-6 or value < -CERTIFIED) and value <= gap + CERTIFIED


def test_a_base_disk_resting_on_a_closed_mesh_is_a_contact_of_positive_zero():
    """The base disk flush on a closed box's top: distance 0, no collision, and +0.0 (a signed zero
    from the inside test printed as "-0.0000 m" in the runner's summary)."""
    slab = trimesh.creation.box(extents=(0.3, 0.3, 0.1)).apply_translation((0.0, 0.0, -0.05))
    assert slab.is_watertight
    straight = np.asarray(SPEC.straight_state(), np.float64)
    step = judge_step(World(meshes=(MeshObstacle(slab.vertices, slab.faces),)), SPEC, straight, straight, 0.0, 0.05)
    assert step.min_distance == 0.0 and math.copysign(1.0, step.min_distance) == 1.0
    assert step.first_collision_time is None
