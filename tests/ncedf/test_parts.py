"""The still cloud cut into parts (ncedf.parts) and the grid model's convex parts, against closed forms:
boxes and cylinders sampled on their surfaces, their exact distances, a plate's hole."""

import jax.numpy as jnp
import numpy as np
import pytest

from ncedf.grid_model import INNER, REACH, GridModel, grid_distance, still_distance
from ncedf.parts import is_convex, split
from ncedf.presets import sampling_gap

DENSITY = 16.0  # points per m^2, the confined worlds'
COVER = INNER * REACH  # the grid model's span of a convex part's hull from its points, in gaps


def box_points(lower, upper, density: float, rng) -> np.ndarray:
    """Points uniform at ``density`` per m^2 on the six faces of the box [lower, upper] (3,) m."""
    lower, upper = np.asarray(lower, float), np.asarray(upper, float)
    out = []
    for axis in range(3):
        others = [a for a in range(3) if a != axis]
        count = rng.poisson(density * np.prod(upper[others] - lower[others]))
        for side in (lower[axis], upper[axis]):
            face = rng.uniform(lower, upper, (count, 3))
            face[:, axis] = side
            out.append(face)
    return np.concatenate(out)


def cylinder_points(centre, radius: float, height: float, density: float, rng) -> np.ndarray:
    """Points uniform at ``density`` per m^2 on the round face of an upright cylinder on (x, y) =
    ``centre`` over z in [0, height], and on its two discs."""
    side = rng.poisson(density * 2 * np.pi * radius * height)
    angle, z = rng.uniform(0, 2 * np.pi, side), rng.uniform(0, height, side)
    discs = []
    for level in (0.0, height):
        count = rng.poisson(density * np.pi * radius**2)
        r, a = radius * np.sqrt(rng.uniform(0, 1, count)), rng.uniform(0, 2 * np.pi, count)
        discs.append(np.column_stack([centre[0] + r * np.cos(a), centre[1] + r * np.sin(a), np.full(count, level)]))
    return np.concatenate([np.column_stack([centre[0] + radius * np.cos(angle), centre[1] + radius * np.sin(angle), z]),
                           *discs])


def box_distance(x: np.ndarray, lower, upper) -> np.ndarray:
    """(N,) exact signed distance from points x (N, 3) to the box [lower, upper], m."""
    centre, half = 0.5 * (np.asarray(upper) + lower), 0.5 * (np.asarray(upper) - lower)
    q = np.abs(x - centre) - half
    return np.linalg.norm(np.maximum(q, 0.0), axis=1) + np.minimum(q.max(axis=1), 0.0)


def fit(points: np.ndarray, goal, keep_open: float = 0.2):
    points = points.astype(np.float32)
    mask = np.ones(len(points), bool)
    return GridModel(sampling_gap(points), keep_open).fit(points, mask, points, mask, 0.05, np.asarray(goal, float))


@pytest.mark.parametrize("seed", [2, 3])
def test_two_boxes_half_a_metre_apart_are_two_convex_parts_scored_at_their_exact_distance(seed):
    """Two 1 x 2 x 3 m boxes 0.5 m apart along x (less than two sampling gaps: the grid alone
    closes most of the lane between them): two parts, each convex, so the model's distance is
    the distance to the boxes the samples span: at most the exact one (no plane cuts a box's edge
    where its samples stop short of it) and within a few cm of it everywhere round them; the lane's
    midline keeps its 0.25 m."""
    rng = np.random.default_rng(seed)
    boxes = [((1.0, -1.0, 0.0), (2.0, 1.0, 3.0)), ((2.5, -1.0, 0.0), (3.5, 1.0, 3.0))]
    points = np.concatenate([box_points(*box, DENSITY, rng) for box in boxes])
    gap = sampling_gap(points)
    assert 0.5 < 2 * gap
    parts = split(points, gap)
    assert sorted(len(p) for p in parts) == sorted([int(np.sum(points[:, 0] <= 2.0)), int(np.sum(points[:, 0] >= 2.5))])
    assert all(is_convex(points[p], gap, COVER) for p in parts)
    fitted = fit(points, (5.0, 0.0, 1.5))
    assert int(np.sum(fitted.parts.present)) == 2
    queries = rng.uniform((0.0, -2.0, -0.5), (4.5, 2.0, 3.5), (4000, 3))
    exact = np.minimum(*[box_distance(queries, *box) for box in boxes])
    queries = queries[exact > 0]
    exact = exact[exact > 0]
    model = np.asarray(still_distance(fitted, jnp.asarray(queries, jnp.float32)))
    to_points = np.min(np.linalg.norm(queries[:, None] - points[None], axis=-1), axis=1)
    assert np.all(model <= to_points + 1e-5)
    assert np.all(model <= exact + 1e-5) and np.all(model >= exact - 0.05)
    lane = np.column_stack([np.full(9, 2.25), np.linspace(-0.8, 0.8, 9), np.full(9, 1.5)])
    assert np.all(np.asarray(still_distance(fitted, jnp.asarray(lane, jnp.float32))) >= 0.25 - 1e-5)


@pytest.mark.parametrize("seed", range(5))
def test_a_pillar_is_never_cut_along_its_length(seed):
    """An 8 m pillar of radius 0.25 m sampled at the confined worlds' density: one part, convex,
    closed as one polytope that holds the round face to within the chord between samples and cuts
    its box's vertical edges (a point at 45 degrees and 0.33 m from the axis is inside the box, 0.08 m
    from the pillar)."""
    rng = np.random.default_rng(seed)
    points = cylinder_points((3.0, 0.0), 0.25, 8.0, DENSITY, rng)
    gap = sampling_gap(points)
    parts = split(points, gap)
    assert len(parts) == 1 and is_convex(points, gap, COVER)
    fitted = fit(points, (5.0, 0.0, 3.0))
    assert int(np.sum(fitted.parts.present)) == 1
    corners = np.array([[3.0 + 0.33 * np.cos(a), 0.33 * np.sin(a), 4.0] for a in np.pi / 4 * np.array([1, 3, 5, 7])])
    assert np.all(np.asarray(still_distance(fitted, jnp.asarray(corners, jnp.float32))) > 0.0)
    angle, z = np.meshgrid(np.linspace(0, 2 * np.pi, 36), np.linspace(0.5, 7.5, 15))
    face = np.column_stack([3.0 + 0.25 * np.cos(angle.ravel()), 0.25 * np.sin(angle.ravel()), z.ravel()])
    assert np.all(np.asarray(still_distance(fitted, jnp.asarray(face, jnp.float32))) <= 0.05)


def test_a_thin_plate_with_a_hole_wider_than_the_cover_is_not_convex():
    """A 4 x 4 m plate 2 cm thick with a 1.2 m square hole, sampled on both faces and the hole's
    sides: every point lies on the hull's boundary (within the plate's thickness), but the hull's
    faces span the hole, farther than ``COVER`` gaps from every point: not convex, so the grid keeps
    the hole open."""
    rng = np.random.default_rng(0)
    points = box_points((3.0, -2.0, -2.0), (3.02, 2.0, 2.0), DENSITY, rng)
    points = points[np.max(np.abs(points[:, 1:]), axis=1) > 0.6]
    gap = sampling_gap(points)
    assert 0.6 > COVER * gap
    assert not is_convex(points, gap, COVER)
    fitted = fit(points, (4.0, 0.0, 0.0))
    assert not np.any(fitted.parts.present)
    assert float(grid_distance(fitted.grid, jnp.asarray([3.01, 0.0, 0.0]))) >= 0.2


def test_parts_that_shut_the_goal_in_go_to_the_grid():
    """A goal between two boxes 0.45 m apart, less than twice the room kept open round it (0.3 m):
    as two polytopes the boxes would leave it no way out, so both are closed on the grid instead."""
    rng = np.random.default_rng(0)
    points = np.concatenate([box_points((1.0, -1.0, 0.0), (2.0, 1.0, 3.0), DENSITY, rng),
                             box_points((2.45, -1.0, 0.0), (3.45, 1.0, 3.0), DENSITY, rng)])
    assert len([p for p in split(points, sampling_gap(points)) if is_convex(points[p], sampling_gap(points), COVER)]) == 2
    apart = fit(points, (5.0, 0.0, 1.5), keep_open=0.3)
    assert int(np.sum(apart.parts.present)) == 2
    shut = fit(points, (2.225, 0.0, 1.5), keep_open=0.3)
    assert not np.any(shut.parts.present)
    assert np.all(np.asarray(grid_distance(shut.grid, jnp.asarray(points, jnp.float32))) <= 0)
