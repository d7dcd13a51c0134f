"""The mount (``ncedf.mount``): the first link stays above its base plane, so the surface under
the base counts for the other links only, and ``ours`` moves a robot that stands on a floor."""

import dataclasses
import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ncedf.broad_phase import BroadPhase, rollout_min_distances
from ncedf.controller import Controller, config_from_dict, config_to_dict
from ncedf.convex import fit_polytopes, robot_clearance
from ncedf.geometry import mesh_grid_coords, robot_surface_points
from ncedf.mount import Mount, holds, link_mask, marked, off_mount, on_mount
from ncedf.obstacle_model import model_clearance
from ncedf.presets import observe, ours
from ncedf.robot import RobotSpec, forward_kinematics, sample_arc_lengths
from ncedf.shapes import make_shape


def _corner_states(spec: RobotSpec) -> np.ndarray:
    """(K, 1, 3) states of one link with two chambers at their limits (the largest bends), every order."""
    third = 3 * spec.length - spec.l_min - spec.l_max
    return np.array([[p] for p in set(itertools.permutations((spec.l_min, spec.l_max, third)))], np.float32)


def _lowest(spec: RobotSpec, arcs: np.ndarray) -> np.ndarray:
    """(K,) the lowest height of link 1's surface (a dense mesh of it) in each state (K, 1, 3), m."""
    coords = jnp.asarray(mesh_grid_coords(96, 96)[None])
    surface = jax.vmap(lambda a: robot_surface_points(coords, a, spec))(jnp.asarray(arcs))
    return np.asarray(surface[..., 2]).min(axis=(1, 2))


def test_the_first_link_never_goes_below_its_base_plane_where_the_bound_holds_and_does_where_it_fails():
    spec = RobotSpec(1)
    arcs = np.concatenate([_corner_states(spec), np.asarray(sample_arc_lengths(jax.random.PRNGKey(0), spec,
                                                                               (200, 1)))])
    assert holds(spec) and _lowest(spec, arcs).min() >= -1e-5
    # Chambers that bend a link past pi: its far end comes down through the plane.
    loose = RobotSpec(1, length=1.0, radius=0.2, l_min=0.3, l_max=1.7)
    assert loose.max_bend() > np.pi and not holds(loose)
    assert _lowest(loose, _corner_states(loose)).min() < -0.1


def _floor_and_box(reach: float):
    """A floor patch 1 cm under the base (half of it on the mount) and a box of points above it."""
    rng = np.random.default_rng(0)
    floor = np.column_stack([rng.uniform(-2 * reach, 2 * reach, (300, 2)), np.full(300, -0.01)])
    box = rng.uniform([1.0, -0.5, 1.0], [2.0, 0.5, 2.0], (100, 3))
    return np.concatenate([floor, box]).astype(np.float32)


def test_the_mounts_points_count_for_every_link_but_the_first_by_brute_force_and_the_broad_phase():
    spec, mount = RobotSpec(3), Mount(0.7)
    points = _floor_and_box(mount.reach)
    mask = np.ones(len(points), bool)
    on = on_mount(mount, points)
    assert 0 < on.sum() < 300 and not on[300:].any()
    shape = make_shape("spheres", spec)
    arcs = sample_arc_lengths(jax.random.PRNGKey(1), spec, (6, 4, 3))
    per_link = jax.vmap(jax.vmap(lambda a: shape.link_distances(jnp.asarray(points), a)))(arcs)  # (6, 4, M, P)
    first, others = np.asarray(per_link[:, :, 0, ~on]), np.asarray(per_link[:, :, 1:])
    expected = np.minimum(first.min(axis=-1), others.min(axis=(-2, -1)))
    masks = link_mask(mount, points, mask, spec.n_links)
    assert masks.shape == (3, len(points)) and (masks[0] == ~on).all() and masks[1:].all()
    brute = rollout_min_distances(None, shape, arcs, jnp.asarray(points), jnp.asarray(masks))
    every_pair = BroadPhase(k1=len(points), k2=3 * len(points))  # the broad phase keeping every pair: exact
    broad = rollout_min_distances(every_pair, shape, arcs, jnp.asarray(points), jnp.asarray(masks))
    np.testing.assert_allclose(brute, expected, atol=1e-5)
    np.testing.assert_allclose(broad, expected, atol=1e-5)
    with_floor = np.asarray(per_link).min(axis=(-2, -1))
    # The floor under the base holds every state within 1 cm of it (the balls dip below); without it most are farther
    assert (with_floor <= 0.01).all() and (expected >= with_floor - 1e-6).all() and (expected > 0.1).mean() > 0.5
    assert link_mask(None, points, mask, 3) is mask
    np.testing.assert_array_equal(off_mount(mount, points, mask), ~on)


def test_ours_moves_a_robot_standing_on_a_floor_that_without_the_mount_it_holds_still():
    """A floor of points 2 cm under the base, the goal ahead and low: ``ours`` takes the MPPI action,
    which passes the safety check; without the mount the check fails that action and holding still
    too (the first link's covering ball dips into the floor's polytope), so every candidate fails."""
    spec = RobotSpec(2)
    rng = np.random.default_rng(2)
    floor = np.column_stack([rng.uniform(-3, 3, (400, 2)), np.full(400, -0.02)]).astype(np.float32)
    config = ours(spec, observe(floor, floor))
    assert config.mount == Mount(spec.radius + 0.25 * spec.length)
    config = dataclasses.replace(config, mppi=dataclasses.replace(config.mppi, samples=32, horizon=4))
    assert config_from_dict(config_to_dict(config)) == config
    goal, shape = np.array([2.5, 0.0, 1.0], np.float32), make_shape("spheres", spec)
    controller = Controller(spec, shape, config)
    state = controller.init(jax.random.PRNGKey(0))
    action, _, info = controller.step(state, spec.straight_state(), goal, floor)
    assert int(info.action_choice) == 0 and float(info.action_clearance) >= config.mppi.safety_margin
    assert float(np.abs(action).max()) > 0.05
    unmounted = Controller(spec, shape, dataclasses.replace(config, mount=None))
    arc, _, points, mask, model, _ = unmounted._inputs(state, spec.straight_state(), goal, floor)
    blind = unmounted.check_moves(arc, points, mask, model)
    moves = jnp.stack([jnp.asarray(action), jnp.zeros_like(action)])  # the action, and no motion
    assert (np.asarray(blind(moves)) < config.mppi.safety_margin).all()


@pytest.mark.parametrize("reach", [0.0, -1.0])
def test_a_mount_needs_a_positive_reach(reach):
    with pytest.raises(ValueError, match="Mount.reach"):
        Mount(reach)


def _box_surface(lower, upper, n: int, seed: int) -> np.ndarray:
    """n points on the surface of the box [lower, upper] (each on a face chosen at random)."""
    rng = np.random.default_rng(seed)
    lower, upper = np.asarray(lower, float), np.asarray(upper, float)
    points = rng.uniform(lower, upper, (n, 3))
    axis, side = rng.integers(0, 3, n), rng.integers(0, 2, n)
    points[np.arange(n), axis] = np.where(side == 1, upper[axis], lower[axis])
    return points.astype(np.float32)


def test_polytopes_wholly_under_the_base_plane_are_no_obstacle_to_the_first_link_alone():
    """A slab of floor under the base and a box above: marked, the floor's polytope leaves the first
    link's bound and keeps the others'; the bound stays below the exact distance from the body to the
    points the first link counts (the box) and those the others count (both), by brute force."""
    spec = RobotSpec(3)
    floor = _box_surface([-3, -3, -0.3], [3, 3, -0.02], 1500, 0)
    box = _box_surface([1.5, -0.5, 1.5], [2.5, 0.5, 2.5], 300, 1)
    polytopes = fit_polytopes(np.concatenate([floor, box]), 1.0)
    assert int(polytopes.present.sum()) == 2
    fitted = marked(Mount(0.7), polytopes)
    assert fitted.mount.tolist()[:2] in ([True, False], [False, True]) and marked(None, polytopes) is polytopes
    assert marked(Mount(0.7), fit_polytopes(box, 1.0)).mount is None  # nothing under the plane: unchanged
    arcs = sample_arc_lengths(jax.random.PRNGKey(3), spec, (60, spec.n_links))
    frames = forward_kinematics(arcs, spec)
    bound = np.asarray(robot_clearance(arcs, frames, spec, fitted))
    plain = np.asarray(robot_clearance(arcs, frames, spec, polytopes))
    exact = make_shape("exact", spec)
    per_link = np.asarray(jax.vmap(lambda a: exact.link_distances(jnp.asarray(np.concatenate([floor, box])), a))(arcs))
    truth = np.minimum(per_link[:, 0, len(floor):].min(axis=-1), per_link[:, 1:].min(axis=(-2, -1)))
    assert (bound <= truth + 1e-5).all() and (bound >= plain - 1e-6).all()
    clear = truth > 0.3  # the states whose body keeps clear by brute force (the others bend into the floor)
    assert (plain < 0).all() and clear.sum() >= 10 and (bound[clear] > 0).all()  # the first ball dips into the floor


def test_the_grid_model_is_fitted_without_the_mount_and_the_first_link_keeps_its_margin():
    """A floor 2 cm under the base and a wall with a window in front (not convex: the grid model):
    fitted by ``ours`` with the mount, the first link's bound at the start keeps the safety margin
    (without the mount the start itself is in the floor's closed cells), and a state bent into the
    floor beyond the mount is scored in it, below its exact distance to the points."""
    spec = RobotSpec(2)
    rng = np.random.default_rng(4)
    floor = np.column_stack([rng.uniform(-3, 5, (800, 2)), np.full(800, -0.02)])
    yz = rng.uniform([-3, 0.5], [3, 5], (600, 2))
    yz = yz[np.max(np.abs(yz - [0, 2.7]), axis=1) > 0.6]  # a window 1.2 m wide round the goal's height
    wall = np.column_stack([np.full(len(yz), 3.5), yz])
    points = np.concatenate([floor, wall]).astype(np.float32)
    config = ours(spec, observe(points, points))
    assert type(config.model).__name__ == "GridModel" and config.mount is not None
    goal = np.array([4.5, 0.0, 2.7], np.float32)
    start, down = spec.straight_state(), np.array([[1.7, 2.3, 2.0], [1.7, 2.3, 2.0]], np.float32)
    bounds = {}
    for mount in (config.mount, None):
        controller = Controller(spec, make_shape("spheres", spec), dataclasses.replace(config, mount=mount))
        padded, mask = controller.pad_points(points)  # seen still once already: the model holds them
        state = controller.init(jax.random.PRNGKey(0))._replace(previous=padded, previous_mask=mask)
        model = controller._inputs(state, start, goal, points)[4]
        arcs = jnp.asarray(np.stack([start, down]))
        bounds[mount] = np.asarray(model_clearance(model, arcs, forward_kinematics(arcs, spec), spec))
    exact = make_shape("exact", spec)
    assert bounds[config.mount][0] >= config.mppi.safety_margin > bounds[None][0]
    depth = float(exact.min_distance(jnp.asarray(points), jnp.asarray(down)))
    assert bounds[config.mount][1] <= depth + 1e-5 and depth < 0
