"""ncedf.convex against independent truths: the closed-form signed distance of a box and of a sphere,
the Euclidean distance to a rotated box's surface (dense), the robot's closed-form
signed distance over a dense grid on a box, and the controller's safety check in
front of a box sampled only at its corners."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jitted import polytope_distance, robot_clearance, step_clearance
from ncedf.controller import Controller, ControllerConfig
from ncedf.convex import (CLEARANCE_CHUNK, CONVEX_TOLERANCE, COVER_SPHERES, MAX_CLUSTERS, _fit_group, clusters,
                          fit_polytope, fit_polytopes, fit_sphere, hull_depth, static_rows)
from ncedf.geometry import robot_signed_distance
from ncedf.mppi import MPPIConfig, init_state, mppi_step
from ncedf.obstacle_model import ConvexModel
from ncedf.recovery import RouteRecovery
from ncedf.robot import RobotSpec, forward_kinematics, sample_arc_lengths
from ncedf.safety import SafetyFilter
from ncedf.shapes import make_shape, sphere_cover_radius
from solids import ported_wall, solid_wall, sphere_surface


def _box_surface(rng, centre, size, density):
    """Uniform points on the faces of an axis-aligned box, ``density`` per m^2 (at least 3 a face)."""
    centre, half = np.asarray(centre, float), 0.5 * np.asarray(size, float)
    out = []
    for axis in range(3):
        a, b = [i for i in range(3) if i != axis]
        n = max(3, int(round(density * 4 * half[a] * half[b])))
        for sign in (-1.0, 1.0):
            p = np.empty((n, 3))
            p[:, axis] = sign * half[axis]
            p[:, a] = rng.uniform(-half[a], half[a], n)
            p[:, b] = rng.uniform(-half[b], half[b], n)
            out.append(centre + p)
    return np.concatenate(out)


#: Both forms of the distance: the device's (the CPU's loop over the clusters here) and all at once
#: (a GPU's).
DENSE = pytest.mark.parametrize("dense", [None, True], ids=["device", "dense"])


def _box_sdf(x, centre, size):
    q = np.abs(x - np.asarray(centre)) - 0.5 * np.asarray(size)
    return np.linalg.norm(np.maximum(q, 0.0), axis=-1) + np.minimum(q.max(axis=-1), 0.0)


@DENSE
def test_a_sparsely_sampled_box_is_closed_exactly(dense):
    # 4 points per m^2 leave holes wider than the robot; the polytope is still the box.
    rng = np.random.default_rng(0)
    boxes = [((2.5, 0.0, 5.0), (1.0, 4.8, 3.0)), ((5.3, 0.0, 2.0), (2.0, 5.0, 1.0))]
    points = np.concatenate([_box_surface(rng, c, s, 4.0) for c, s in boxes])
    poly = fit_polytopes(points, 1.0)
    assert int(np.sum(poly.present)) == 2
    x = rng.uniform((-1.0, -4.0, -1.0), (8.0, 4.0, 8.0), (5000, 3))
    truth = np.min([_box_sdf(x, c, s) for c, s in boxes], axis=0)
    d = np.asarray(polytope_distance(jnp.asarray(x, jnp.float32), poly, dense=dense))
    np.testing.assert_allclose(d, truth, atol=1e-5)


@DENSE
def test_a_rotated_box_is_closed_by_its_hull_planes(dense):
    rng = np.random.default_rng(1)
    rot, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    size = np.array([1.0, 2.0, 0.6])
    corners = 0.5 * size * np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)])
    local = np.concatenate([_box_surface(rng, (0.0, 0.0, 0.0), size, 20.0), corners])  # the hull is the box
    lower, upper, normals, offsets = fit_polytope(local @ rot.T)
    assert len(offsets) >= 6  # the six face planes besides the bounding box's
    poly = fit_polytopes(local @ rot.T, 1.0)
    x_local = rng.uniform(-2.0, 2.0, (4000, 3))
    truth = _box_sdf(x_local, (0.0, 0.0, 0.0), size)
    d = np.asarray(polytope_distance(jnp.asarray(x_local @ rot.T, jnp.float32), poly, dense=dense))
    assert np.all(d <= truth + 1e-5)  # a lower bound outside, minus at least the depth inside
    inside_points = np.asarray(polytope_distance(jnp.asarray(local @ rot.T, jnp.float32), poly, dense=dense))
    assert np.all(inside_points <= 1e-5)
    far = np.abs(truth) > 0.15  # away from the surface the sides agree
    assert np.all((d[far] < 0) == (truth[far] < 0))


@DENSE
def test_a_sampled_sphere_is_closed_as_its_ball_moving_with_it(dense):
    # 30 points on a 0.5 m sphere (the cluttered scene's moving spheres): the model is the sphere
    # itself, where the points' bounding box sticks out at its corners and their hull cuts under it.
    rng = np.random.default_rng(5)
    centre, radius, v = np.array([4.0, -1.0, 2.2]), 0.5, np.array([0.0, 1.0, -0.8])
    points = sphere_surface(rng, centre, radius, 30)
    poly = fit_polytopes(points, 1.0, velocity=np.tile(v, (30, 1)))
    assert int(np.sum(poly.present)) == 1 and bool(poly.ball[0])
    x = rng.uniform(-3.0, 3.0, (2000, 3)).astype(np.float32) + centre.astype(np.float32)
    t = rng.uniform(0.0, 2.0, 2000).astype(np.float32)
    truth = np.linalg.norm(x - t[:, None] * v - centre, axis=1) - radius
    d = np.asarray(polytope_distance(jnp.asarray(x), poly, jnp.asarray(t), dense=dense))
    np.testing.assert_allclose(d, truth, atol=2e-5)
    box = fit_polytopes(points, 1.0)._replace(ball=jnp.zeros(MAX_CLUSTERS, bool))  # the same points as a polytope
    d_box = np.asarray(polytope_distance(jnp.asarray(x), box, dense=dense))
    truth_now = np.linalg.norm(x - centre, axis=1) - radius
    assert np.max(d_box - truth_now) > 0.02 and np.min(d_box - truth_now) < -0.1  # both wrong ways, by far


def test_touching_spheres_in_one_moving_cluster_are_each_a_ball():
    # Four 0.5 m spheres stacked, touching (the charging port's rows), 30 points each: single linkage
    # joins them into one cluster on no one sphere; its halves, and theirs, each lie on one.
    rng = np.random.default_rng(8)
    centres = np.array([[3.0, -4.0, z] for z in (3.5, 2.5, 1.5, 0.5)])
    points = np.concatenate([sphere_surface(rng, c, 0.5, 30) for c in centres])
    v = np.tile([0.0, 1.0, 0.0], (len(points), 1))
    assert len(np.unique(clusters(points, 1.0, bounds=False))) == 1
    poly = fit_polytopes(points, 1.0, velocity=v, bounds=())
    assert int(np.sum(poly.present)) == 4 and bool(np.all(np.asarray(poly.ball)[np.asarray(poly.present)]))
    found = np.asarray(poly.centre)[np.asarray(poly.present)]
    np.testing.assert_allclose(found[np.argsort(-found[:, 2])], centres, atol=1e-4)
    box = _box_surface(rng, (0.0, 0.0, 2.0), (1.0, 1.0, 4.0), 8.0)  # a moving column: no part on a sphere
    column = fit_polytopes(box, 1.0, velocity=np.tile([0.0, 1.0, 0.0], (len(box), 1)), bounds=())
    assert int(np.sum(column.present)) == 1 and not bool(column.ball[0])
    for few in ([0], [0, 30, 60], [0, 1, 2, 30, 31, 60, 61]):  # on no one sphere, too few to halve
        lone = fit_polytopes(points[few], 1.0, velocity=v[few], bounds=())
        assert int(np.sum(lone.present)) == 1 and not bool(lone.ball[0])


def test_only_clusters_on_a_sphere_are_balls():
    rng = np.random.default_rng(6)
    points = sphere_surface(rng, (1.0, -2.0, 0.5), 0.7, 12)
    found = fit_sphere(points)
    assert found is not None
    np.testing.assert_allclose(found[0], (1.0, -2.0, 0.5), atol=1e-5)
    assert found[1] == pytest.approx(0.7, abs=1e-5)
    assert np.all(np.linalg.norm(points - found[0], axis=1) <= found[1])  # the ball holds every point
    plane = np.concatenate([rng.uniform(-1.0, 1.0, (50, 2)), np.full((50, 1), 0.3)], axis=1).astype(np.float32)
    rot, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    tilted = (plane @ rot.T).astype(np.float32)  # coplanar up to float32 rounding
    noisy = sphere_surface(rng, (0.0, 0.0, 0.0), 0.5, 30) + rng.normal(scale=0.02, size=(30, 3))
    dome = sphere_surface(rng, (0.0, 0.0, 0.0), 1.0, 400)
    dome = dome[dome[:, 2] > 0.3]  # its bounding box is smaller than its sphere's ball
    box = _box_surface(rng, (0.0, 0.0, 0.0), (1.0, 1.0, 1.0), 30.0)
    for cluster in (box, plane, tilted, noisy, dome, points[:4]):
        assert fit_sphere(cluster) is None
    assert not bool(np.any(fit_polytopes(box, 1.0).ball))


def test_a_fit_from_the_cache_is_the_fit_from_scratch():
    # The controller refits every step; the static group's clusters come from the cache.
    rng = np.random.default_rng(7)
    static = _box_surface(rng, (2.5, 0.0, 0.0), (1.0, 5.0, 2.0), 4.0)
    groups = np.r_[np.zeros(30, bool), np.ones(len(static), bool)]
    fits = []
    for centre in ((4.0, 0.0, 2.2), (4.0, 0.0, 2.16), (4.0, 0.0, 2.12)):
        cloud = np.concatenate([sphere_surface(np.random.default_rng(8), centre, 0.5, 30), static])
        fits.append(fit_polytopes(cloud, 1.0, groups))
    _fit_group.cache_clear()
    fresh = fit_polytopes(cloud, 1.0, groups)
    for cached, new in zip(fits[-1], fresh):
        np.testing.assert_array_equal(cached, new)
    assert int(np.sum(fresh.present)) == 2 and int(np.sum(fresh.ball)) == 1


def test_clusters_split_at_the_link_distance():
    rng = np.random.default_rng(2)
    a = _box_surface(rng, (0.0, 0.0, 0.0), (1.0, 1.0, 1.0), 30.0)
    b = _box_surface(rng, (1.8, 0.0, 0.0), (1.0, 1.0, 1.0), 30.0)  # 0.8 m apart
    labels = clusters(np.concatenate([a, b]), 0.5)
    assert len(np.unique(labels[: len(a)])) == 1 and len(np.unique(labels[len(a):])) == 1
    assert labels[0] != labels[-1]
    assert len(np.unique(clusters(np.concatenate([a, b]), 1.0))) == 1


def _longest_tree_edge(points):
    """The longest edge of the points' Euclidean minimum spanning tree (dense), m: single linkage
    at a shorter distance splits them."""
    d = np.linalg.norm(points[:, None] - points[None], axis=-1)
    inside, best, longest = np.zeros(len(points), bool), d[0].copy(), 0.0
    inside[0] = True
    for _ in range(len(points) - 1):
        j = int(np.argmin(np.where(inside, np.inf, best)))
        longest, inside[j] = max(longest, best[j]), True
        best = np.minimum(best, d[j])
    return longest


@pytest.mark.parametrize("seed", range(4))
def test_a_box_sampled_more_sparsely_than_the_link_stays_whole(seed):
    # 1 point per m^2 (3 on the smallest faces): gaps between samples wider than the link, so single
    # linkage alone cuts the box's faces into fragments with holes between them; the fragments'
    # boxes merge, and the polytope is the box (each face holds a sample).
    rng = np.random.default_rng(seed)
    boxes = [((2.5, 0.0, 5.0), (1.0, 4.8, 3.0)), ((5.3, 0.0, 2.0), (2.0, 5.0, 1.0)), ((2.5, 0.0, 0.0), (1.0, 5.0, 2.0))]
    parts = [_box_surface(rng, c, s, 1.0) for c, s in boxes]
    assert max(_longest_tree_edge(p) for p in parts) > 1.0
    labels = clusters(np.concatenate(parts), 1.0)
    starts = np.cumsum([0] + [len(p) for p in parts])
    assert [len(np.unique(labels[a:b])) for a, b in zip(starts[:-1], starts[1:])] == [1, 1, 1]
    assert len(np.unique(labels)) == 3
    poly = fit_polytopes(np.concatenate(parts), 1.0)
    x = rng.uniform((-1.0, -4.0, -2.0), (8.0, 4.0, 8.0), (5000, 3))
    truth = np.min([_box_sdf(x, c, s) for c, s in boxes], axis=0)
    np.testing.assert_allclose(np.asarray(polytope_distance(jnp.asarray(x, jnp.float32), poly)), truth, atol=1e-5)


def test_clusters_whose_bounds_lie_within_the_link_merge_only_within_a_group():
    # Two sparse flat patches whose bounds are 0.9 m apart and their points over 1 m: one obstacle
    # at a link of 1 m, unless they are in different groups (static and moving points never merge).
    a = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    b = a + (1.9, 0.5, 0.0)
    assert np.min(np.linalg.norm(a[:, None] - b[None], axis=-1)) > 1.0
    points = np.concatenate([a, b])
    assert len(np.unique(clusters(points, 1.0))) == 1
    apart = clusters(points, 1.0, np.repeat([0, 1], 3))
    assert len(np.unique(apart[:3])) == len(np.unique(apart[3:])) == 1 and apart[0] != apart[3]
    assert len(np.unique(clusters(points, 1.0, bounds=False))) == 2
    farther = clusters(np.concatenate([a, a + (2.1, 0.5, 0.0)]), 1.0)  # bounds 1.1 m apart
    assert len(np.unique(farther[:3])) == len(np.unique(farther[3:])) == 1 and farther[0] != farther[3]


@DENSE
def test_capacity_keeps_the_largest_clusters_and_no_points_no_obstacle(dense):
    rng = np.random.default_rng(3)
    small = [rng.normal(scale=0.05, size=(5, 3)) + (3.0 * i, 0.0, 0.0) for i in range(MAX_CLUSTERS)]
    big = _box_surface(rng, (0.0, 10.0, 0.0), (1.0, 1.0, 1.0), 30.0)
    poly = fit_polytopes(np.concatenate(small + [big]), 1.0)
    assert bool(np.all(poly.present))
    inside = polytope_distance(jnp.asarray([[0.0, 10.0, 0.0]], jnp.float32), poly, dense=dense)
    assert float(inside[0]) == pytest.approx(-0.5)
    empty = fit_polytopes(np.zeros((0, 3)), 1.0)
    assert not bool(np.any(empty.present))
    assert np.isinf(float(polytope_distance(jnp.zeros((1, 3)), empty, dense=dense)[0]))


def test_static_rows_are_the_unmoved_real_ones():
    prev = np.arange(12, dtype=np.float32).reshape(4, 3)
    now = prev.copy()
    now[1] += 0.01
    mask = np.array([True, True, True, False])
    np.testing.assert_array_equal(static_rows(now, mask, prev, np.array([True, True, False, True])),
                                  [True, False, False, False])


@DENSE
def test_robot_clearance_is_a_tight_lower_bound_of_the_body_clearance(dense):
    spec = RobotSpec(2)
    centre, size = (1.2, 0.3, 2.0), (0.8, 0.8, 0.8)
    g = np.linspace(-0.5, 0.5, 41)
    a, b = np.meshgrid(g, g)
    faces = []
    for axis in range(3):
        for sign in (-0.5, 0.5):
            p = np.zeros((a.size, 3))
            others = [i for i in range(3) if i != axis]
            p[:, axis], p[:, others[0]], p[:, others[1]] = sign, a.ravel(), b.ravel()
            faces.append(p * np.asarray(size) + centre)
    grid = jnp.asarray(np.concatenate(faces), jnp.float32)  # 2 cm spacing on the faces
    poly = fit_polytopes(np.asarray(grid)[::7], 1.0)
    arcs = sample_arc_lengths(jax.random.PRNGKey(0), spec, (64, spec.n_links))
    bound = np.asarray(robot_clearance(arcs, forward_kinematics(arcs, spec), spec, poly, dense=dense))
    truth = np.asarray(jax.vmap(lambda arc: jnp.min(robot_signed_distance(grid, arc, spec)))(arcs))
    clear = truth > 0.02  # configurations off the box (inside it the grid misses the depth)
    assert clear.sum() > 20
    assert np.all(bound[clear] <= truth[clear] + 1e-5)
    slack = float(np.max(sphere_cover_radius(jnp.asarray(3.0), spec, COVER_SPHERES))) - spec.radius
    assert np.all(bound[clear] >= truth[clear] - slack - 0.02)


def test_the_clearance_scores_states_alike_in_passes_and_all_at_once():
    # More states than one pass holds (two passes and a remainder), against boxes, a rotated box's
    # planes and a moving ball, each state at its own time.
    rng = np.random.default_rng(8)
    spec = RobotSpec(3)
    corners = 0.5 * np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)])
    rot, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    rotated = (np.concatenate([_box_surface(rng, (0, 0, 0), (1, 1, 1), 20.0), corners]) @ rot.T) + (-2.0, 2.0, 2.0)
    ball = sphere_surface(rng, (0.0, -3.0, 2.5), 0.5, 30)
    points = np.concatenate([_box_surface(rng, (3.0, 0.0, 3.0), (1.0, 2.0, 1.0), 4.0), rotated, ball])
    velocity = np.zeros_like(points)
    velocity[-len(ball):] = (0.0, 0.5, -0.2)
    poly = fit_polytopes(points, 1.0, velocity=velocity)
    assert int(poly.ball.sum()) == 1 and int(poly.valid.sum()) >= 6
    n = 2 * CLEARANCE_CHUNK + 77
    arcs = sample_arc_lengths(jax.random.PRNGKey(1), spec, (n, spec.n_links))
    frames = forward_kinematics(arcs, spec)
    t = jnp.asarray(rng.uniform(0.0, 1.0, n), jnp.float32)
    passes = np.asarray(robot_clearance(arcs, frames, spec, poly, t, dense=False))
    at_once = np.asarray(robot_clearance(arcs, frames, spec, poly, t, dense=True))
    assert np.ptp(passes) > 1.0
    np.testing.assert_allclose(at_once, passes, atol=1e-5)


@pytest.mark.parametrize("platform", ["cpu", "cuda"])
def test_only_the_cpu_scores_the_clearance_in_a_loop(platform):
    # A GPU runs a loop's steps and a branch's predicate one after another; lowered for one, the
    # clearance has neither.
    spec = RobotSpec(2)
    poly = fit_polytopes(_box_surface(np.random.default_rng(9), (2.0, 0.0, 3.0), (1.0, 1.0, 1.0), 4.0), 1.0)
    arcs = jnp.full((8, spec.n_links, 3), spec.length)
    traced = robot_clearance.trace(arcs, forward_kinematics(arcs, spec), spec, poly, 0.1)
    text = traced.lower(lowering_platforms=(platform,)).as_text()
    assert ("stablehlo.while" in text) == (platform == "cpu")


# A one-link robot bends through a slab that is observed only at its eight corners (dt = 1 s).
SPEC = RobotSpec(1)
ARC = np.full((1, 3), 2.0, np.float32)
CROSSING = np.array([[0.3, -0.15, -0.15]], np.float32)
SLAB = np.array([[x, y, z] for x in (-0.7, -0.6) for y in (-0.5, 0.5) for z in (1.7, 2.4)], np.float32)
CONFIG = ControllerConfig(MPPIConfig(samples=16, horizon=3, covariance=1e-10, dt=1.0, max_points=64),
                          broad_phase=None, safety=SafetyFilter(), model=ConvexModel(1.0))
CORE = CONFIG.mppi


def _fit(controller, state, cloud):
    """The controller's obstacle model of ``cloud`` given the state's previous observation."""
    return controller.config.model.fit(*controller.pad_points(cloud), state.previous, state.previous_mask, CORE.dt)


def test_safety_check_sees_the_slab_between_its_corners():
    shape = make_shape("exact", SPEC)
    points, mask = jnp.asarray(SLAB), jnp.ones(len(SLAB), bool)
    actions = jnp.asarray(CROSSING)[None]
    corners_only = float(step_clearance(CORE.dt, 4, None, shape, jnp.asarray(ARC), actions, points, mask)[0])
    assert corners_only > CORE.safety_margin  # the points alone let the crossing through
    closed = float(step_clearance(CORE.dt, 4, None, shape, jnp.asarray(ARC), actions, points, mask,
                                  model=fit_polytopes(SLAB, CONFIG.model.link))[0])
    assert closed < 0.0

    nominal = jnp.broadcast_to(jnp.asarray(CROSSING), (CORE.horizon, 1, 3))
    state = init_state(SPEC, CORE, jax.random.PRNGKey(0))._replace(nominal=nominal)
    goal = jnp.asarray([-1.24, 0.0, 1.33])
    action, _, info = mppi_step(SPEC, CONFIG, shape, state, jnp.asarray(ARC), goal, points, mask,
                                fit_polytopes(SLAB, CONFIG.model.link))
    assert int(info.action_choice) != 0
    assert float(step_clearance(CORE.dt, 4, None, shape, jnp.asarray(ARC), action[None], points, mask,
                                model=fit_polytopes(SLAB, 1.0))[0]) >= CORE.safety_margin
    unmodelled, _, _ = mppi_step(SPEC, dataclasses.replace(CONFIG, model=None, safety=None), shape, state,
                                 jnp.asarray(ARC), goal, points, mask)
    np.testing.assert_allclose(unmodelled, CROSSING, atol=1e-4)  # the cloud alone lets the crossing through


def test_the_controller_clusters_moving_and_static_points_apart():
    mppi = Controller(SPEC, make_shape("exact", SPEC), CONFIG)
    state = mppi.init(jax.random.PRNGKey(0))
    above = SLAB + np.array([0.0, 0.0, 0.8], np.float32)  # 0.1 m above the slab: within the link distance
    cloud = np.concatenate([above, SLAB])
    poly = _fit(mppi, state, cloud)
    assert int(np.sum(poly.present)) == 1  # nothing seen before: all one moving cluster
    np.testing.assert_allclose(np.asarray(poly.upper[0]), above.max(axis=0))
    _, state, _ = mppi.step(state, ARC, np.array([-1.24, 0.0, 1.33]), cloud)
    moved = above + np.array([0.0, 0.0, 0.05], np.float32)
    poly = _fit(mppi, state, np.concatenate([moved, SLAB]))
    assert int(np.sum(poly.present)) == 2
    bounds = sorted((tuple(np.asarray(poly.lower[c])), tuple(np.asarray(poly.upper[c]))) for c in range(2))
    np.testing.assert_allclose(bounds[0], [SLAB.min(axis=0), SLAB.max(axis=0)])
    np.testing.assert_allclose(bounds[1], [moved.min(axis=0), moved.max(axis=0)])
    speeds = sorted(float(np.asarray(poly.velocity[c])[2]) for c in range(2))
    np.testing.assert_allclose(speeds, [0.0, 0.05 / CORE.dt], atol=1e-6)


@DENSE
def test_a_moving_polytope_is_scored_where_it_will_be(dense):
    rng = np.random.default_rng(4)
    corners = 0.5 * np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)])
    points = np.concatenate([_box_surface(rng, (0.0, 0.0, 0.0), (1.0, 1.0, 1.0), 30.0), corners])
    v = np.array([0.3, -0.2, 0.5])
    moving = fit_polytopes(points, 1.0, velocity=np.tile(v, (len(points), 1)))
    at_rest = fit_polytopes(points, 1.0)
    x = rng.uniform(-3.0, 3.0, (500, 3)).astype(np.float32)
    t = rng.uniform(0.0, 2.0, 500).astype(np.float32)
    np.testing.assert_allclose(np.asarray(polytope_distance(jnp.asarray(x), moving, jnp.asarray(t), dense=dense)),
                               _box_sdf(x - t[:, None] * v, (0.0, 0.0, 0.0), (1.0, 1.0, 1.0)), atol=1e-5)
    np.testing.assert_allclose(np.asarray(polytope_distance(jnp.asarray(x), at_rest, jnp.asarray(t), dense=dense)),
                               _box_sdf(x, (0.0, 0.0, 0.0), (1.0, 1.0, 1.0)), atol=1e-5)


@DENSE
def test_a_turning_polytope_is_scored_at_its_nearest_reachable_place(dense):
    """``turning``: a box and a ball moving at |v| may turn within t; the bound is the distance to
    the nearest of their places within |v| t (brute force over 4000 directions), for points that
    no such place reaches."""
    rng = np.random.default_rng(6)
    corners = 0.5 * np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)])
    box_points = np.concatenate([_box_surface(rng, (0.0, 0.0, 0.0), (1.0, 1.0, 1.0), 30.0), corners])
    ball_points = sphere_surface(rng, np.array([0.0, 0.0, 0.0]), 0.5, 30)
    v = np.array([0.3, -0.2, 0.5])
    directions = rng.normal(size=(4000, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    for points, exact in ((box_points, lambda y: _box_sdf(y, (0.0, 0.0, 0.0), (1.0, 1.0, 1.0))),
                          (ball_points, lambda y: np.linalg.norm(y, axis=-1) - 0.5)):
        poly = fit_polytopes(points, 1.0, velocity=np.tile(v, (len(points), 1)))
        x = rng.uniform(-3.0, 3.0, (300, 3)).astype(np.float32)
        t = rng.uniform(0.0, 2.0, 300).astype(np.float32)
        reach = t * np.linalg.norm(v)
        keep = exact(x) > reach
        d = np.asarray(polytope_distance(jnp.asarray(x), poly, jnp.asarray(t), dense=dense, turning=True))[keep]
        brute = np.array([np.min(exact(p - r * directions)) for p, r in zip(x[keep], reach[keep])])
        assert np.all(d <= brute + 1e-5) and np.all(brute - d < 0.01)


def test_a_cluster_that_is_not_convex_is_left_to_the_cloud():
    solid, ported = solid_wall(), ported_wall()
    # Closed form: the points halfway through the port's inner faces lie half the thickness deep.
    assert hull_depth(solid) < CONVEX_TOLERANCE
    assert hull_depth(ported) == pytest.approx(0.25, abs=1e-9)
    assert int(np.sum(fit_polytopes(solid, 1.0).present)) == 1
    assert int(np.sum(fit_polytopes(ported, 1.0).present)) == 0
    # Beside the ported wall a box stays in the model: the clusters are judged one by one.
    box = _box_surface(np.random.default_rng(6), (3.0, 0.0, 2.0), (1.0, 1.0, 1.0), 20.0)
    both = fit_polytopes(np.concatenate([ported, box]), 1.0)
    assert int(np.sum(both.present)) == 1
    np.testing.assert_allclose(both.lower[0], box.min(axis=0), atol=1e-6)


def test_convex_link_is_validated():
    with pytest.raises(ValueError, match="ConvexModel.link"):
        ConvexModel(-1.0)
    with pytest.raises(ValueError, match="recovery plans round the obstacle model"):
        dataclasses.replace(CONFIG, model=None, recovery=RouteRecovery())


def test_the_controller_merges_only_static_clusters_by_their_bounds():
    # Two 3-point patches, bounds 0.9 m apart and points over 1 m apart: at the first step every
    # row counts as moving and they stay two clusters; once they stand still they are one.
    mppi = Controller(SPEC, make_shape("exact", SPEC), CONFIG)
    state = mppi.init(jax.random.PRNGKey(0))
    a = np.array([[3.0, 0.0, 0.0], [4.0, 0.0, 0.0], [3.0, 1.0, 0.0]], np.float32)
    cloud = np.concatenate([a, a + np.array([1.9, 0.5, 0.0], np.float32)])
    assert int(np.sum(_fit(mppi, state, cloud).present)) == 2
    _, state, _ = mppi.step(state, ARC, np.array([-1.24, 0.0, 1.33]), cloud)
    poly = _fit(mppi, state, cloud)
    assert int(np.sum(poly.present)) == 1
    np.testing.assert_allclose(np.asarray(poly.lower[0]), cloud.min(axis=0))
    np.testing.assert_allclose(np.asarray(poly.upper[0]), cloud.max(axis=0))
