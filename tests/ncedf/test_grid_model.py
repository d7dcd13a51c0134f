"""The grid model and the guide against independent truths: brute-force distances to the points,
a sampled wall closed and its opening kept open, and path lengths round a wall in closed form."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.ndimage import map_coordinates
from scipy.spatial import cKDTree

from ncedf.controller import Controller, ControllerConfig
from ncedf.convex import fit_polytopes, polytope_distance
from ncedf.grid_model import (EXACT_BAND, LINK, REACH, GridModel, fit_clearance, grid_box, parts_field,
                               smooth_distance, still_distance)
from ncedf.guide import Guide, _gradient_at, guided_distance
from ncedf.presets import Observation, ours, sampling_gap
from ncedf.robot import BASE, RobotSpec, forward_kinematics
from ncedf.shapes import make_shape

RNG = np.random.default_rng(7)  # the tests' other random draws


def wall(density: float, window: float, size: float = 6.0, x: float = 3.0, seed: int = 0) -> np.ndarray:
    """Points uniform at ``density`` per m^2 on the plane x = ``x`` over y, z in [-size/2, size/2]
    less a square window of side ``window`` centred at y = z = 0 (its edges sampled too)."""
    rng = np.random.default_rng(seed)
    count = rng.poisson(density * size * size)
    yz = rng.uniform(-size / 2, size / 2, (count, 2))
    yz = yz[np.max(np.abs(yz), axis=1) > window / 2]
    return np.column_stack([np.full(len(yz), x), yz]).astype(np.float32)


def fit(points: np.ndarray, goal, gap: float, keep_open: float = 0.2):
    mask = np.ones(len(points), bool)
    return GridModel(gap, keep_open).fit(points, mask, points, mask, 0.05, np.asarray(goal, np.float64))


def test_the_grid_distance_is_a_lower_bound_of_the_distance_to_the_points():
    points = RNG.uniform(-2.0, 2.0, (300, 3)).astype(np.float32)
    fitted = fit(points, (0.0, 0.0, 3.0), gap=0.3)
    queries = RNG.uniform(-4.0, 4.0, (4000, 3)).astype(np.float32)
    truth = np.min(np.linalg.norm(queries[:, None] - points[None], axis=-1), axis=1)
    bound = np.asarray(still_distance(fitted, jnp.asarray(queries)))
    assert np.all(bound <= truth + 1e-5)
    # Outside the cloud's box by more than the reach (REACH gaps) no closed cell is farther from a
    # point than the reach: there the bound is within it and two half cell diagonals.
    outside = np.max(np.abs(queries), axis=1) > 2.0 + REACH * 0.3
    assert np.all(truth[outside] - bound[outside] <= REACH * 0.3 + float(fitted.grid.spacing) * np.sqrt(3.0) + 1e-5)


def test_the_smooth_distance_is_scipys_trilinear_interpolation_and_climbs_away_from_the_points():
    points = RNG.uniform(-1.0, 1.0, (200, 3)).astype(np.float32)
    fitted = fit(points, (0.0, 0.0, 3.0), gap=0.3)
    grid = fitted.grid
    values, origin, h = grid.array(), np.asarray(grid.origin), float(grid.spacing)
    inside = origin + h * (np.asarray(values.shape) - 1)  # the last cell centres
    queries = RNG.uniform(origin, inside, (2000, 3)).astype(np.float32)
    truth = map_coordinates(values.astype(np.float64), ((queries - origin) / h).T, order=1)
    if np.any(fitted.parts.present):  # where the parts' distance is less, it (ncedf.convex, tested apart)
        truth = np.minimum(truth, np.asarray(polytope_distance(jnp.asarray(queries), fitted.parts)))
    smooth = smooth_distance(fitted, jnp.asarray(queries))
    np.testing.assert_allclose(np.asarray(smooth), truth, atol=1e-4)
    # In free space its gradient is finite and points away from the nearest point (up the distance).
    grad = np.asarray(jax.vmap(jax.grad(lambda x: smooth_distance(fitted, x)))(jnp.asarray(queries)))
    nearest = points[cKDTree(points).query(queries)[1]]
    free = np.asarray(smooth) > 2 * h
    assert free.sum() > 100 and np.all(np.isfinite(grad))
    assert np.mean(np.sum(grad[free] * (queries[free] - nearest[free]), axis=1) > 0) > 0.9


def test_above_the_grid_the_bound_holds_and_is_at_least_the_height_above_it():
    """A low slab of points and queries up to 10 m above the grid's box (where a robot's upper links
    are): the bound holds, and is at least the height above the box (everything it measures lies in
    the box), where the distance to a cell at the box's top less the height had made them look deep
    inside the slab."""
    points = np.concatenate([RNG.uniform([1.0, -1.0, 0.0], [3.0, 1.0, 0.5], (400, 3))]).astype(np.float32)
    fitted = fit(points, (2.0, 0.0, 1.5), gap=0.3)
    top = float(fitted.grid.origin[2] + fitted.grid.spacing * (fitted.grid.array().shape[2] - 1))
    queries = RNG.uniform([-4.0, -4.0, top], [8.0, 4.0, top + 10.0], (3000, 3)).astype(np.float32)
    truth = np.min(np.linalg.norm(queries[:, None] - points[None], axis=-1), axis=1)
    bound = np.asarray(still_distance(fitted, jnp.asarray(queries)))
    assert np.all(bound <= truth + 1e-5)
    assert np.all(bound >= queries[:, 2] - top - 1e-5)


def test_a_free_cell_near_the_points_holds_the_exact_distance_to_the_points_and_filled_cells():
    """Free cells within EXACT_BAND of the points (of 6000 drawn): the nearer of the points (brute
    force) and the centres of the closed cells that hold no point (closed cells have negative values)."""
    points = RNG.uniform(-2.0, 2.0, (300, 3)).astype(np.float32)
    fitted = fit(points, (0.0, 0.0, 3.0), gap=0.3)
    values, h, origin = fitted.grid.array(), float(fitted.grid.spacing), np.asarray(fitted.grid.origin, np.float64)
    # The cells that hold a point as the fit rounds them: by its float64 origin and spacing, not the grid's float32.
    lower, spacing, _ = grid_box(points.astype(np.float64), np.stack([BASE, (0.0, 0.0, 3.0)]), GridModel(0.3, 0.2))
    hit = np.zeros(values.shape, bool)
    hit[tuple(np.rint((points - lower) / spacing).astype(int).T)] = True
    filled = origin + h * np.argwhere((values < 0) & ~hit)
    free = origin + h * np.argwhere(values >= 0)
    free = free[np.all(np.abs(free) < 2.0 + EXACT_BAND, axis=1)]  # the points' box and the band round it
    free = free[RNG.choice(len(free), 6000, replace=False)]
    to_points = np.min(np.linalg.norm(free[:, None] - points[None], axis=-1), axis=1)
    near = to_points < EXACT_BAND - h
    assert near.sum() >= 1000
    to_filled = cKDTree(filled).query(free[near])[0]
    cells = tuple(np.rint((free[near] - origin) / h).astype(int).T)
    np.testing.assert_allclose(values[cells], np.minimum(to_points[near], to_filled), atol=1e-5)


def test_a_wall_sampled_at_the_papers_density_is_closed_and_its_opening_kept():
    """4 points per m^2 with a 2.4 m window: every point of the wall away from the window and the
    border is closed (a ball of the robot's radius there meets the model), the window's centre has
    room for the robot (0.2 m) and a margin."""
    points = wall(4.0, 2.4)
    gap = sampling_gap(points)
    assert 0.3 < gap < 0.8
    fitted = fit(points, (4.0, 0.0, 0.0), gap)
    yz = np.stack(np.meshgrid(np.linspace(-2.3, 2.3, 24), np.linspace(-2.3, 2.3, 24)), -1).reshape(-1, 2)
    solid = yz[np.max(np.abs(yz), axis=1) > 1.2 + 0.5]
    on_wall = jnp.asarray(np.column_stack([np.full(len(solid), 3.0), solid]), jnp.float32)
    assert np.all(np.asarray(still_distance(fitted, on_wall)) < 0.2)
    assert float(still_distance(fitted, jnp.asarray([3.0, 0.0, 0.0]))) > 0.2 + 0.1


def test_the_points_alone_leave_the_robot_room_in_the_wall_that_the_model_closes():
    """The reason for the model: somewhere on the sampled wall the nearest point is farther than the
    robot's radius, while the model closes it."""
    points = wall(4.0, 2.4)
    fitted = fit(points, (4.0, 0.0, 0.0), sampling_gap(points))
    yz = np.stack(np.meshgrid(np.linspace(-2.3, 2.3, 47), np.linspace(-2.3, 2.3, 47)), -1).reshape(-1, 2)
    yz = yz[np.max(np.abs(yz), axis=1) > 1.2 + 0.5]
    probes = np.column_stack([np.full(len(yz), 3.0), yz]).astype(np.float32)
    nearest = np.min(np.linalg.norm(probes[:, None] - points[None], axis=-1), axis=1)
    assert nearest.max() > 0.2
    assert np.all(np.asarray(still_distance(fitted, jnp.asarray(probes))) < 0.2)


def test_the_guide_measures_the_way_round_a_wall_through_its_window():
    """A solid wall (dense points) with a window at y in [2, 3.2]: from in front of the wall at
    y = 0 to the goal behind it, the guided distance is the path through the window (closed
    form: two straight legs), not the straight line, within the grid's metric error."""
    count = 40000
    yz = RNG.uniform(-4.0, 4.0, (count, 2))
    yz = yz[~((yz[:, 0] > 2.0) & (yz[:, 0] < 3.2) & (np.abs(yz[:, 1]) < 0.6))]
    points = np.column_stack([np.full(len(yz), 3.0), yz]).astype(np.float32)
    goal, start = np.array([4.0, 0.0, 0.0]), np.array([2.0, 0.0, 0.0])
    fitted = fit(points, goal, gap=0.1)
    field = Guide(0.2).fit(fitted, goal)
    hole = np.array([3.0, 2.6, 0.0])
    legs = np.linalg.norm(start - hole) + np.linalg.norm(hole - goal)
    guided = float(guided_distance(field, jnp.asarray(start, jnp.float32)))
    assert legs * 0.95 < guided < legs * 1.15
    assert guided > 1.5 * np.linalg.norm(goal - start)
    assert float(guided_distance(field, jnp.asarray(goal, jnp.float32))) < 3 * float(field.spacing)


def test_the_clearance_of_a_robot_is_at_most_its_exact_clearance_to_the_points():
    spec = RobotSpec(2)
    points = wall(16.0, 1.0, x=1.5)
    mask = np.ones(len(points), bool)
    fitted = GridModel(sampling_gap(points), 0.2).fit(points, mask, points, mask, 0.05, np.array([2.0, 0.0, 2.0]))
    arcs = np.asarray(jax.random.uniform(jax.random.PRNGKey(0), (64, 2, 3), minval=1.7, maxval=2.3), np.float32)
    frames = forward_kinematics(jnp.asarray(arcs), spec)
    bound = np.asarray(fit_clearance(jnp.asarray(arcs), frames, spec, fitted))
    exact = make_shape("exact", spec)
    truth = np.array([float(exact.min_distance(jnp.asarray(points), jnp.asarray(a), jnp.ones(len(points), bool)))
                      for a in arcs])
    assert np.all(bound <= truth + 1e-4)


def test_ours_steps_with_the_grid_model_and_the_guide_on_the_programs_its_warm_up_compiled():
    """The first step sees no point still (a far grid over the cloud's box), the second closes the
    wall: both grids have one shape, so the warm-up's programs serve both steps."""
    from ncedf import mppi as mppi_module

    spec = RobotSpec(3)
    points = wall(4.0, 1.6)
    config = ours(spec, Observation(len(points), convex=False, gap=sampling_gap(points)))
    config = ControllerConfig(**{**vars(config), "mppi": config.mppi.__class__(
        **{**vars(config.mppi), "samples": 64, "horizon": 5})})
    controller = Controller(spec, make_shape("spheres", spec), config)
    state = controller.init(jax.random.PRNGKey(0))
    arc, goal = np.asarray(spec.straight_state(), np.float32), np.array([4.0, 0.0, 1.0], np.float32)
    programs = [mppi_module.mppi_step]
    controller.warm_up(state, arc, goal, points)
    warm = [p._cache_size() for p in programs]
    for _ in range(2):  # the second step sees the points still: the grid closes them
        action, state, info = controller.step(state, arc, goal, points)
    assert [p._cache_size() for p in programs] == warm
    fitted, _ = controller.fit_model(state, *controller.pad_points(points), goal)
    assert float(np.min(fitted.grid.array())) < 0  # the wall closed at the second step
    assert action.shape == (3, 3) and np.all(np.isfinite(np.asarray(action)))
    assert np.isfinite(float(info.predicted_min_distance))


def test_clouds_of_other_gaps_share_the_compiled_step_and_it_is_the_step_of_the_whole_settings():
    """The grid model's gap is measured from each cloud (a preset's), and only the host-side fit reads
    it: a controller for another sampling of the wall steps on the program already compiled, and its
    action is that of the step of the whole settings, bit for bit."""
    from ncedf import mppi as mppi_module

    spec = RobotSpec(3)
    arc, goal = np.asarray(spec.straight_state(), np.float32), np.array([4.0, 0.0, 1.0], np.float32)
    added, gaps = [], []
    for seed in (0, 1):  # two samplings of one wall: other gaps, one capacity
        points = wall(4.0, 1.6, seed=seed)
        config = ours(spec, Observation(len(points), convex=False, gap=sampling_gap(points)))
        config = ControllerConfig(**{**vars(config), "mppi": config.mppi.__class__(
            **{**vars(config.mppi), "samples": 32, "horizon": 4})})
        gaps.append(config.model.gap)
        controller = Controller(spec, make_shape("spheres", spec), config)
        state = controller.init(jax.random.PRNGKey(0))
        before = mppi_module.mppi_step._cache_size()
        action, _, _ = controller.step(state, arc, goal, points)
        added.append(mppi_module.mppi_step._cache_size() - before)
    # The second cloud's action, from the program the first compiled, is its whole settings' step.
    whole = mppi_module.mppi_step(controller.core_spec, config, controller.core_shape, state.mppi,
                                  *controller._inputs(state, arc, goal, points))[0]
    np.testing.assert_array_equal(np.asarray(action), np.asarray(whole) * controller.unit)
    assert gaps[0] != gaps[1] and added[1] == 0


def test_the_parts_field_is_the_polytopes_distance_at_the_cell_centres_and_grids_in_a_bucket_share_a_program():
    """Two boxes' polytopes on grids of 20 x 20 x 20 and 21 x 20 x 19 cells (both padded to 8192): each
    value the distance at its cell's centre (numpy's grid of centres), one compiled program for both."""
    boxes = np.concatenate([RNG.uniform((0.5, 0.5, 0.5), (1.0, 1.5, 2.0), (200, 3)),
                            RNG.uniform((-1.5, -1.0, 0.2), (-1.0, 1.0, 0.6), (200, 3))]).astype(np.float32)
    parts = fit_polytopes(boxes, link=0.3)
    polytope_distance.clear_cache()
    grids = (((20, 20, 20), np.array([-2.0, -2.0, -1.0]), 0.2), ((21, 20, 19), np.zeros(3), 0.15))
    fields = [parts_field(parts, origin, h, shape) for shape, origin, h in grids]
    assert polytope_distance._cache_size() == 1
    for field, (shape, origin, h) in zip(fields, grids):
        centres = np.stack(np.meshgrid(*(origin[i] + h * np.arange(n) for i, n in enumerate(shape)), indexing="ij"),
                           axis=-1).astype(np.float32)
        assert field.shape == shape
        np.testing.assert_array_equal(field, np.asarray(polytope_distance(jnp.asarray(centres), parts)))


def test_a_guide_needs_the_grid_model():
    with pytest.raises(ValueError, match="GridModel"):
        ControllerConfig(guide=Guide(0.2))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_an_opening_of_the_robots_diameter_and_a_margin_stays_open_in_a_closed_wall(seed):
    """16 points per m^2 (the confined worlds' density) on a wall with a 1 m window (the robot's
    0.4 m diameter and 0.3 m each side): the wall is closed, the window has room for the robot's
    radius, and the guided distance from 1 m in front to 1 m behind is the straight 2 m through it
    (round the 6 m wide wall would be over 6 m)."""
    points = wall(16.0, 1.0, seed=seed)
    goal, start = np.array([4.0, 0.0, 0.0]), np.array([2.0, 0.0, 0.0])
    fitted = fit(points, goal, sampling_gap(points))
    yz = np.stack(np.meshgrid(np.linspace(-2.3, 2.3, 24), np.linspace(-2.3, 2.3, 24)), -1).reshape(-1, 2)
    solid = yz[np.max(np.abs(yz), axis=1) > 0.5 + 0.5]
    on_wall = jnp.asarray(np.column_stack([np.full(len(solid), 3.0), solid]), jnp.float32)
    assert np.all(np.asarray(still_distance(fitted, on_wall)) < 0.2)
    centre = tuple(np.rint((np.array([3.0, 0.0, 0.0]) - fitted.grid.origin) / fitted.grid.spacing).astype(int))
    assert fitted.grid.array()[centre] >= 0.2
    field = Guide(0.2).fit(fitted, goal)
    assert 2.0 <= float(guided_distance(field, jnp.asarray(start, jnp.float32))) < 2.0 * 1.15


def thick_wall(density: float, window: float, thickness: float = 0.3, size: float = 6.0, seed: int = 0):
    """Points uniform at ``density`` per m^2 on both faces of a wall x in [3, 3 + ``thickness``] over
    y, z in [-size/2, size/2], less a square window of side ``window`` centred at y = z = 0, and on
    the window's four sides."""
    rng = np.random.default_rng(seed)
    faces = [wall(density, window, size, x, seed=int(rng.integers(1 << 30))) for x in (3.0, 3.0 + thickness)]
    for axis in (1, 2):
        for side in (-window / 2, window / 2):
            count = rng.poisson(density * thickness * window)
            points = np.column_stack([rng.uniform(3.0, 3.0 + thickness, count), np.zeros(count),
                                      rng.uniform(-window / 2, window / 2, count)])
            points[:, [axis, 3 - axis]] = np.column_stack([np.full(count, side), points[:, 2]])
            faces.append(points.astype(np.float32))
    return np.concatenate(faces)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_window_through_a_thick_wall_narrower_than_the_first_closings_span_stays_open(seed):
    """16 points per m^2 on a 0.3 m thick wall with a 1 m window, narrower than twice the first
    reach (that closing alone fills it): the window's centre keeps its half-width less the edges'
    move at the first reach ((2 - sqrt 3) gaps) and two half cell diagonals, and both faces of the
    wall are closed."""
    points = thick_wall(16.0, 1.0, seed=seed)
    gap = sampling_gap(points)
    assert 1.0 < 2 * REACH * gap
    fitted = fit(points, np.array([4.5, 0.0, 0.0]), gap)
    yz = np.stack(np.meshgrid(np.linspace(-2.3, 2.3, 24), np.linspace(-2.3, 2.3, 24)), -1).reshape(-1, 2)
    solid = yz[np.max(np.abs(yz), axis=1) > 0.5 + 0.5]
    for x in (3.0, 3.3):
        on_wall = jnp.asarray(np.column_stack([np.full(len(solid), x), solid]), jnp.float32)
        assert np.all(np.asarray(still_distance(fitted, on_wall)) < 0.2)
    room = 0.5 - (2.0 - np.sqrt(3.0)) * gap - float(fitted.grid.spacing) * np.sqrt(3.0)
    assert room > 0.2
    assert float(still_distance(fitted, jnp.asarray([3.15, 0.0, 0.0]))) >= room


def pillars(density: float, spacing: float, radius: float = 0.25, height: float = 4.0, seed: int = 0) -> np.ndarray:
    """Points uniform at ``density`` per m^2 on the round faces of a 3 x 3 grid of upright
    cylinders (axes at x in {2, 2 + spacing, 2 + 2 spacing}, y in {-spacing, 0, spacing}, z in
    [0, height]) and their top discs."""
    rng = np.random.default_rng(seed)
    clouds = []
    for cx in 2.0 + spacing * np.arange(3):
        for cy in spacing * np.arange(-1, 2):
            side = rng.poisson(density * 2 * np.pi * radius * height)
            angle, z = rng.uniform(0, 2 * np.pi, side), rng.uniform(0, height, side)
            top = rng.poisson(density * np.pi * radius**2)
            r, a = radius * np.sqrt(rng.uniform(0, 1, top)), rng.uniform(0, 2 * np.pi, top)
            clouds.append(np.column_stack([cx + radius * np.cos(angle), cy + radius * np.sin(angle), z]))
            clouds.append(np.column_stack([cx + r * np.cos(a), cy + r * np.sin(a), np.full(top, height)]))
    return np.concatenate(clouds).astype(np.float32)


@pytest.mark.parametrize("seed", [0, 1])
def test_the_lanes_between_separate_pillars_stay_open_and_their_surfaces_closed(seed):
    """16 points per m^2 on nine pillars of radius 0.25 m whose faces stand 1 m apart (the robot's
    0.4 m diameter and 0.3 m each side), narrower than the closing's span (twice the reach): every
    point of a pillar's round face is closed to the robot's radius, the lanes' midpoints have room
    for the robot's radius and a margin, and the guided distance along a lane is the straight line
    (round the field it would be over 1.5 times as long)."""
    points = pillars(16.0, 1.5, seed=seed)
    gap = sampling_gap(points)
    assert 2 * REACH * gap > 1.0
    goal, start = np.array([6.0, 0.75, 2.0]), np.array([1.0, 0.75, 2.0])
    fitted = fit(points, goal, gap)
    angle, z = np.meshgrid(np.linspace(0, 2 * np.pi, 24), np.linspace(0.5, 3.5, 7))
    face = np.column_stack([2.0 + 0.25 * np.cos(angle.ravel()), 0.25 * np.sin(angle.ravel()), z.ravel()])
    assert np.all(np.asarray(still_distance(fitted, jnp.asarray(face, jnp.float32))) < 0.2)
    lanes = np.array([[x, y, 2.0] for x in (2.0, 3.5, 5.0) for y in (-0.75, 0.75)], np.float32)
    assert np.all(np.asarray(still_distance(fitted, jnp.asarray(lanes))) >= 0.2 + 0.05)
    field = Guide(0.2).fit(fitted, goal)
    straight = float(np.linalg.norm(goal - start))
    assert straight <= float(guided_distance(field, jnp.asarray(start, jnp.float32))) < straight * 1.15


@pytest.mark.parametrize("seed", [0, 1])
def test_a_lane_narrower_than_a_samples_hole_stays_open_between_separate_pillars(seed):
    """The pillars' faces 0.7 m apart, less than the widest hole between their samples (two gaps):
    joined at two gaps the pillars were one surface and its closing shut the lanes (a negative
    field); each pillar closed on its own keeps them open, every point of a face closed. A lane's
    midpoint keeps its half-width less the faces' move ((2 - sqrt 3) gaps at a reach of two gaps)
    and two half cell diagonals (a point's cell centre, and the query's)."""
    points = pillars(16.0, 1.2, seed=seed)
    gap = sampling_gap(points)
    assert 2 * gap > 0.7 > LINK * gap
    fitted = fit(points, np.array([6.0, 0.6, 2.0]), gap)
    angle, z = np.meshgrid(np.linspace(0, 2 * np.pi, 24), np.linspace(0.5, 3.5, 7))
    face = np.column_stack([3.2 + 0.25 * np.cos(angle.ravel()), 0.25 * np.sin(angle.ravel()), z.ravel()])
    assert np.all(np.asarray(still_distance(fitted, jnp.asarray(face, jnp.float32))) < 0.2)
    lanes = np.array([[x, y, z] for x in (2.0, 3.2, 4.4) for y in (-0.6, 0.6) for z in (1.0, 2.0, 3.0)], np.float32)
    room = 0.35 - (2.0 - np.sqrt(3.0)) * gap - float(fitted.grid.spacing) * np.sqrt(3.0)
    assert room > 0.05
    assert np.all(np.asarray(still_distance(fitted, jnp.asarray(lanes))) >= room)


def test_the_guides_gradient_at_a_cell_is_numpys_over_the_whole_grid():
    values = np.random.default_rng(0).normal(size=(7, 5, 9))
    full = [np.gradient(values, 0.2, axis=k) for k in range(3)]
    for cell in np.ndindex(values.shape):  # the border cells' one-sided differences too
        np.testing.assert_array_equal(_gradient_at(values, np.array(cell), 0.2), [g[cell] for g in full])


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_pose_goals_way_in_stays_open_where_the_samples_holes_are_as_wide_as_the_port(seed):
    """5 points per m^2 (the charging port's density) on a wall with a 1 m port: the widest hole
    expected between samples is about as wide as the port. With a pose goal whose approach axis runs
    through the port, its corridor (0.4 m round a 2 m segment behind the goal) leaves the robot's
    radius and margin (0.2 + 0.05 m) along the way in, while the wall beside the corridor is closed
    as it is for a goal in front of it (same grid box, no shrinking)."""
    points = wall(5.0, 1.0, seed=seed)
    gap = sampling_gap(points)
    assert gap > 0.45
    pose = np.eye(4)
    pose[:3, :3] = [[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]]  # approach axis (z) along +x
    pose[:3, 3] = [3.0, 0.0, 0.0]
    mask = np.ones(len(points), bool)
    model = GridModel(gap, 0.2, corridor_radius=0.4, corridor_length=2.0)
    in_port = jnp.asarray([[x, 0.0, 0.0] for x in (1.5, 2.0, 2.5, 3.0)], jnp.float32)
    with_pose = model.fit(points, mask, points, mask, 0.05, pose)
    assert np.all(np.asarray(still_distance(with_pose, in_port)) >= 0.2 + 0.05)
    in_front = model.fit(points, mask, points, mask, 0.05, np.array([2.0, 0.0, 0.0]))
    yz = np.stack(np.meshgrid(np.linspace(-2.3, 2.3, 24), np.linspace(-2.3, 2.3, 24)), -1).reshape(-1, 2)
    beside = yz[np.linalg.norm(yz, axis=1) > 0.4 + 1.0]
    on_wall = jnp.asarray(np.column_stack([np.full(len(beside), 3.0), beside]), jnp.float32)
    np.testing.assert_array_equal(np.asarray(still_distance(with_pose, on_wall)),
                                  np.asarray(still_distance(in_front, on_wall)))


def test_a_moving_ball_beside_a_wall_is_closed_and_scored_where_it_will_be():
    # A wall's points stay still, a 0.5 m sphere's 30 points move at v: the grid holds the wall,
    # the sphere is its ball moved t v ahead, where its 30 points leave caps deep enough for a link.
    from ncedf.geometry import robot_signed_distance
    from ncedf.obstacle_model import model_clearance
    from ncedf.robot import sample_arc_lengths

    rng = np.random.default_rng(11)
    spec, dt, v = RobotSpec(n_links=4), 0.05, np.array([0.0, 1.0, 0.0])
    direction = rng.normal(size=(30, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    centre = np.array([0.6, 0.0, 1.6])
    before = np.concatenate([wall(5.0, 1.0), centre + 0.5 * direction]).astype(np.float32)
    now = before.copy()
    now[-30:] += (v * dt).astype(np.float32)
    mask, none = np.ones(len(now), bool), np.zeros(len(now), bool)
    model = GridModel(0.4, 0.2)
    assert not np.any(model.fit(now, mask, before, none, dt, np.array([4.0, 0.0, 0.0])).moving.present)
    fitted = model.fit(now, mask, before, mask, dt, np.array([4.0, 0.0, 0.0]))
    assert int(np.sum(fitted.moving.present)) == 1 and bool(fitted.moving.ball[0])
    np.testing.assert_allclose(np.asarray(fitted.moving.velocity[0]), v, atol=1e-4)

    arcs = sample_arc_lengths(jax.random.PRNGKey(1), spec, (400, spec.n_links))
    t = jnp.asarray(rng.uniform(0.0, 1.0, 400), jnp.float32)
    bound = np.asarray(model_clearance(fitted, arcs, forward_kinematics(arcs, spec), spec, t))

    def clearance(points):  # the body's least signed distance to points (N, 3) at each state's time
        return np.asarray(jax.vmap(lambda arc, s: jnp.min(robot_signed_distance(points + s * v, arc, spec)))(
            arcs, t))

    # Clear of a ball, the body's distance to it is its distance to the centre less the radius.
    sphere = clearance(jnp.asarray((centre + v * dt)[None], jnp.float32)) - 0.5
    samples = clearance(jnp.asarray(now[-30:]))
    near = (sphere > 0.0) & (sphere < 1.0)
    assert near.sum() > 20
    assert np.all(bound[near] <= sphere[near] + 1e-3)
    assert np.max(samples[near] - sphere[near]) > 0.05  # the points alone leave room the ball does not
