"""The surface model of a sparse cloud (ncedf.cloud): fill points between near neighbours only,
on the surface they span, covering holes the raw cloud leaves; a wall the robot would poke
through between raw points is seen."""

import jax
import jax.numpy as jnp
import numpy as np
from scipy.spatial import cKDTree

from ncedf.cloud import fill_count, fill_surface, fill_weights, interpolate
from ncedf.robot import RobotSpec, forward_kinematics
from ncedf.shapes import make_shape

fill = jax.jit(fill_surface, static_argnums=2)


def _padded(points: np.ndarray, capacity: int):
    out = np.zeros((capacity, 3), np.float32)
    out[: len(points)] = points
    mask = np.zeros(capacity, bool)
    mask[: len(points)] = True
    return jnp.asarray(out), jnp.asarray(mask)


def _random_plane(n: int, side: float, seed: int) -> np.ndarray:
    xy = np.random.default_rng(seed).uniform(0.0, side, (n, 2))
    return np.column_stack([xy, np.zeros(n)]).astype(np.float32)


def test_fill_points_lie_on_the_plane_and_cover_its_holes():
    side, density = 4.0, 4.0
    cloud = _random_plane(int(density * side * side), side, seed=0)
    points, mask = _padded(cloud, 80)
    filled, fmask = fill(points, mask, 1.2)
    assert filled.shape[0] == 80 + fill_count(80)
    extra = np.asarray(filled)[np.asarray(fmask)][len(cloud):]
    assert len(extra) > 10 * len(cloud)
    np.testing.assert_allclose(extra[:, 2], 0.0, atol=1e-6)
    # Inside the samples' hull, or extrapolated at most max_edge / 2 beyond it.
    assert extra[:, :2].min() >= -0.6 - 1e-5 and extra[:, :2].max() <= side + 0.6 + 1e-5
    grid = np.stack(np.meshgrid(np.linspace(0.6, side - 0.6, 60), np.linspace(0.6, side - 0.6, 60)), -1).reshape(-1, 2)
    grid = np.column_stack([grid, np.zeros(len(grid))])
    raw_gap = cKDTree(cloud).query(grid)[0]
    filled_gap = cKDTree(np.concatenate([cloud, extra])).query(grid)[0]
    assert np.mean(raw_gap > 0.2) > 0.3
    assert np.mean(filled_gap > 0.2) < np.mean(raw_gap > 0.2) / 3
    assert np.all(filled_gap <= raw_gap + 1e-9)


def test_no_fill_between_points_farther_apart_than_max_edge():
    cloud = _random_plane(60, 3.0, seed=1)
    far = cloud + np.array([4.5, 0.0, 0.0], np.float32)  # a second plate 1.5 m beyond the first
    points, mask = _padded(np.concatenate([cloud, far]), 128)
    max_edge = 1.0
    parents, weights, offsets, valid = (np.asarray(x) for x in fill_weights(points, mask, max_edge))
    p = np.asarray(points)
    used = parents[valid]
    assert np.all(np.linalg.norm(offsets, axis=1) <= max_edge / 2 + 1e-5)
    assert np.all(np.asarray(mask)[used])  # padding is never a parent
    np.testing.assert_allclose(weights.sum(1), 1.0, atol=1e-6)
    assert np.all(weights >= 0)
    for a, b in ((0, 1), (0, 2), (1, 2)):
        both = (weights[valid][:, a] > 0) & (weights[valid][:, b] > 0)
        length = np.linalg.norm(p[used[both, a]] - p[used[both, b]], axis=1)
        assert length.max() <= max_edge + 1e-5
    extra = (np.asarray(interpolate(points, parents, weights)) + offsets)[valid]
    # Nothing in the gap beyond the extrapolation of the plates' edges (max_edge / 2).
    assert not np.any((extra[:, 0] > 3.0 + max_edge / 2 + 1e-5) & (extra[:, 0] < 4.5 - max_edge / 2 - 1e-5))
    np.testing.assert_allclose(extra[:, 2], 0.0, atol=1e-5)  # extrapolated in the plates' plane


def test_a_hole_wider_than_the_edges_reach_is_covered_from_its_rim():
    g = np.arange(-2.0, 2.01, 0.3)
    xy = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    xy = xy[np.linalg.norm(xy, axis=1) > 0.55]  # a round hole of radius 0.55 m in a 0.3 m grid
    cloud = np.column_stack([xy, np.zeros(len(xy))]).astype(np.float32)
    points, mask = _padded(cloud, 256)
    filled, fmask = fill(points, mask, 1.2)
    pts = np.asarray(filled)[np.asarray(fmask)]
    ring = np.column_stack([0.3 * np.cos(np.linspace(0, 2 * np.pi, 24)), 0.3 * np.sin(np.linspace(0, 2 * np.pi, 24)),
                            np.zeros(24)])
    probes = np.vstack([np.zeros((1, 3)), ring])  # the hole's centre and a circle half way to its rim
    raw, seen = cKDTree(cloud).query(probes)[0], cKDTree(pts).query(probes)[0]
    assert raw.min() > 0.24 and raw[0] > 0.54
    assert seen[0] < 0.15 and seen.mean() < 0.6 * raw.mean() and np.all(seen <= raw + 1e-9)
    np.testing.assert_allclose(pts[:, 2], 0.0, atol=1e-5)


def test_isolated_points_get_no_fill():
    centres = np.array([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 2.0, 1.0]], np.float32)  # 2 m apart
    points, mask = _padded(centres, 8)
    _, fmask = fill(points, mask, 1.2)
    assert int(np.asarray(fmask).sum()) == len(centres)


def test_velocities_carry_over_to_the_fill_points():
    cloud = _random_plane(40, 3.0, seed=2)
    points, mask = _padded(cloud, 64)
    parents, weights, _, valid = fill_weights(points, mask, 1.2)
    omega = np.array([0.0, 0.0, 0.5], np.float32)  # rigid rotation about z: v = omega x p
    velocity = jnp.cross(jnp.asarray(omega), points)
    carried = np.asarray(interpolate(velocity, parents, weights))[np.asarray(valid)]
    moved = np.asarray(interpolate(points, parents, weights))[np.asarray(valid)]
    np.testing.assert_allclose(carried, np.cross(omega, moved), atol=1e-5)  # linear in p


def test_a_sparse_wall_hides_from_the_raw_cloud_but_not_from_the_surface_model():
    # A bent 2 m link; a wall across it 0.3 m behind its tip, sampled on a 0.8 m grid with the
    # link's crossing point in the middle of a cell: the body goes through the wall.
    spec = RobotSpec(1)
    arc = jnp.asarray([[1.7, 2.15, 2.15]], jnp.float32)
    tip = np.asarray(forward_kinematics(arc, spec))[-1]
    e1, e2, centre = tip[:3, 0], tip[:3, 1], tip[:3, 3] - 0.3 * tip[:3, 2]
    k = np.arange(-3, 3) + 0.5
    a, b = (x.ravel() for x in np.meshgrid(0.8 * k, 0.8 * k))
    wall = (centre + a[:, None] * e1 + b[:, None] * e2).astype(np.float32)
    exact = make_shape("exact", spec)
    u = np.linspace(-2.4, 2.4, 241)  # the wall itself, 2 cm apart: the truth
    a, b = (x.ravel() for x in np.meshgrid(u, u))
    plane = jnp.asarray(centre + a[:, None] * e1 + b[:, None] * e2, jnp.float32)
    assert float(exact.min_distance(plane, arc)) < -0.15
    points, mask = _padded(wall, 64)
    raw = float(exact.min_distance(points, arc, mask))
    filled, fmask = fill(points, mask, 1.2)
    seen = float(exact.min_distance(filled, arc, fmask))
    assert raw > 0.3  # the raw cloud: clear by far more than the safety margin
    assert seen < 0.0  # the surface model: the body overlaps its points
