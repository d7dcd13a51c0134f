"""Datasets: shapes, exact labels, surface-sample labels, cache keyed by settings."""

import dataclasses

import jax
import numpy as np
import pytest
from scipy.spatial import cKDTree

from ncedf.data import FIELDS, DatasetConfig, ValidationConfig, load_dataset, settings_hash
from ncedf.geometry import link_signed_distance, robot_mesh, sample_link_surface
from ncedf.robot import RobotSpec, config_to_arc_lengths, state_violation

SPEC = RobotSpec(1)
SMALL = DatasetConfig(n_configs=6, grid=6, n_surface=64, n_near=32, seed=3)


@pytest.fixture(scope="module", autouse=True)
def cache(tmp_path_factory):
    path = tmp_path_factory.mktemp("cache")
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("NCEDF_CACHE", str(path))
        yield path


def test_training_set_shapes_and_configurations_are_valid_states():
    data = load_dataset(SMALL, SPEC)
    assert data.points.shape == (6, 6**3 + 32, 3)
    assert data.distances.shape == data.inside.shape == (6, 6**3 + 32)
    assert data.surface.shape == (6, 64, 3)
    assert data.n_samples == 6 * (6**3 + 32 + 64)
    for theta, phi in zip(data.theta, data.phi):
        arc = np.asarray(config_to_arc_lengths(theta, phi, SPEC))[None]
        assert state_violation(arc, SPEC, atol=1e-5) is None


def test_grid_spans_the_box():
    data = load_dataset(SMALL, SPEC)
    grid = data.points[0, : 6**3]
    np.testing.assert_allclose(grid.min(axis=0), SMALL.box_min, atol=1e-6)
    np.testing.assert_allclose(grid.max(axis=0), SMALL.box_max, atol=1e-6)


def test_exact_labels_match_dense_surface_samples_and_mesh_containment():
    """Labels against truths built another way: a KD-tree over 200k surface samples (distance)
    and trimesh containment in a fine mesh of the link (inside flags)."""
    data = load_dataset(SMALL, SPEC)
    for j in range(3):
        theta, phi = float(data.theta[j]), float(data.phi[j])
        dense = np.asarray(sample_link_surface(jax.random.PRNGKey(j), 200_000, theta, phi, SPEC))
        brute, _ = cKDTree(dense).query(data.points[j])
        outside = ~data.inside[j]
        # Samples lie on the surface: never nearer than it; 200k of them leave gaps below 2 cm.
        assert np.all(brute[outside] >= data.distances[j][outside] - 1e-5)
        assert np.max(brute[outside] - data.distances[j][outside]) < 0.02
        arc = np.asarray(config_to_arc_lengths(theta, phi, SPEC))[None]
        mesh = robot_mesh(arc, SPEC, rings=96, around=96)  # polygon error r (1 - cos(pi / 96)) < 0.2 mm
        clear = data.distances[j] > 0.005
        np.testing.assert_array_equal(mesh.contains(data.points[j][clear]), data.inside[j][clear])
        # The surface samples (label 0) lie on the surface: near the dense samples.
        near, _ = cKDTree(dense).query(data.surface[j])
        assert near.max() < 0.02


def test_surface_sample_labels_bound_the_exact_distance_from_above():
    exact = load_dataset(dataclasses.replace(SMALL, n_surface=2000), SPEC)
    approx = load_dataset(dataclasses.replace(SMALL, n_surface=2000, labels="surface-samples"), SPEC)
    np.testing.assert_allclose(exact.points, approx.points, atol=1e-6)
    # The nearest of finitely many surface points is never nearer than the surface.
    assert np.all(approx.distances >= exact.distances - 1e-5)
    far = exact.distances > 0.3
    # ... and with 2000 samples it is close to it away from the surface.
    assert np.median(approx.distances[far] - exact.distances[far]) < 0.03


def test_cache_returns_the_same_set_and_is_keyed_by_the_settings(cache):
    first = load_dataset(SMALL, SPEC)
    path = cache / f"datasetconfig-{first.key}.npz"
    with np.load(path) as f:
        np.testing.assert_array_equal(f["distances"], first.distances)
        marked = {k: f[k] for k in FIELDS}
    marked["distances"] = marked["distances"] + 1.0  # a file the builder would not write: read, not rebuilt
    np.savez(path, **marked)
    again = load_dataset(SMALL, SPEC)
    np.testing.assert_array_equal(again.distances, first.distances + 1.0)
    path.unlink()  # the other tests read the set the builder writes
    assert first.key == again.key
    other = dataclasses.replace(SMALL, seed=4)
    assert settings_hash(other, SPEC) != first.key
    assert settings_hash(SMALL, RobotSpec(1, radius=0.25)) != first.key
    assert settings_hash(SMALL, RobotSpec(3)) == first.key  # link data do not depend on the link count


def test_corrupted_cache_file_is_rebuilt(cache):
    first = load_dataset(SMALL, SPEC)
    path = cache / f"datasetconfig-{first.key}.npz"
    path.write_bytes(b"not an npz")
    again = load_dataset(SMALL, SPEC)
    np.testing.assert_array_equal(first.distances, again.distances)
    with np.load(path) as f:  # written again, whole
        np.testing.assert_array_equal(f["distances"], first.distances)


def test_validation_set_uses_uniform_points_in_the_box_and_exact_labels():
    cfg = ValidationConfig(n_configs=5, n_points=500, n_surface=16, seed=9)
    val = load_dataset(cfg, SPEC)
    assert val.points.shape == (5, 500, 3)
    assert np.all(val.points >= np.array(cfg.box_min)) and np.all(val.points <= np.array(cfg.box_max))
    sd = np.asarray(link_signed_distance(val.points[2], val.theta[2], val.phi[2], SPEC))
    np.testing.assert_allclose(val.distances[2], np.abs(sd), atol=1e-5)
    train = load_dataset(SMALL, SPEC)
    assert not np.isin(val.theta, train.theta).any()


@pytest.mark.parametrize("bad", [dict(n_configs=0), dict(grid=0), dict(n_surface=-1), dict(labels="nearest"),
                                 dict(box_min=(0.0, 0.0, 5.0))])
def test_bad_settings_name_the_bad_field(bad):
    (field,) = bad
    with pytest.raises(ValueError, match=rf"^{field}\b"):
        DatasetConfig(**bad)
