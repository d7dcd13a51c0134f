"""N-CEDF model: encodings, composition through the kinematic chain, save/load checks."""

import dataclasses
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ncedf.geometry import robot_signed_distance
from ncedf.model import (MLP, ModelConfig, ModelError, NCEDF, chord_bounds, encode, init_params, load_model, save_model,
                         softplus)
from ncedf.robot import RobotSpec, arc_lengths_to_config, config_to_arc_lengths, forward_kinematics, sample_arc_lengths

SPEC = RobotSpec(1)


def _model(config=ModelConfig(layers=3, width=8), seed=0):
    return NCEDF(params=init_params(jax.random.PRNGKey(seed), config), config=config, spec=SPEC)


def test_layers_count_dense_layers_including_the_output():
    for layers in (1, 2, 4):
        params = init_params(jax.random.PRNGKey(0), ModelConfig(layers=layers, width=16))
        kernels = [v["kernel"].shape for v in params["params"].values()]
        assert len(kernels) == layers
        assert kernels[-1] == (16 if layers > 1 else 4, 1)


def test_encodings():
    pts = jnp.array([[1.0, 2.0, 3.0], [-0.5, 0.1, 0.2]])
    paper = encode(pts, 0.7, 1.1, "paper")
    np.testing.assert_allclose(paper, [[0.7, 1.1, 1.0, 2.0, 3.0], [0.7, 1.1, -0.5, 0.1, 0.2]], rtol=1e-6)
    bent = encode(pts, 0.7, np.pi / 2, "bending-plane")
    # Rotating by -pi/2 about z maps (x, y) to (y, -x).
    np.testing.assert_allclose(bent, [[0.7, 2.0, -1.0, 3.0], [0.7, 0.1, 0.5, 0.2]], atol=1e-6)


def test_signed_abs_output_is_the_absolute_value_of_the_network():
    raw_cfg = ModelConfig(layers=3, width=8, output="distance")
    abs_cfg = dataclasses.replace(raw_cfg, output="signed-abs")
    params = init_params(jax.random.PRNGKey(1), raw_cfg)
    pts = jax.random.normal(jax.random.PRNGKey(2), (50, 3))
    raw = NCEDF(params, raw_cfg, SPEC).link_distance(pts, 0.4, 0.3)
    assert (raw < 0).any()
    np.testing.assert_allclose(NCEDF(params, abs_cfg, SPEC).link_distance(pts, 0.4, 0.3), np.abs(raw), rtol=1e-6)


def test_robot_distance_is_the_min_over_links_of_the_network_in_each_link_frame():
    model = dataclasses.replace(_model(ModelConfig(layers=2, width=8, encoding="paper", output="distance")),
                                domain=((-100.0,) * 3, (100.0,) * 3))  # all points inside the network's domain
    spec = RobotSpec(3)
    arc = sample_arc_lengths(jax.random.PRNGKey(3), spec, (3,))
    pts = jax.random.uniform(jax.random.PRNGKey(4), (40, 3), minval=-3, maxval=6)
    frames = np.asarray(forward_kinematics(arc, spec))
    theta, phi = arc_lengths_to_config(arc, spec)
    expected = []
    for i in range(3):
        inv = np.linalg.inv(frames[i])
        local = pts @ inv[:3, :3].T + inv[:3, 3]
        x = np.concatenate([np.full((40, 1), theta[i]), np.full((40, 1), phi[i]), local], axis=1)
        expected.append(MLP(2, 8).apply(model.params, jnp.asarray(x, jnp.float32)))
    np.testing.assert_allclose(model.robot_link_distances(pts, arc), np.stack(expected), atol=1e-4)
    np.testing.assert_allclose(model.robot_distance(pts, arc), np.min(expected, axis=0), atol=1e-4)


def test_model_is_a_pytree_that_jits_and_vmaps_over_configurations():
    model = _model()
    spec = RobotSpec(2)
    arcs = sample_arc_lengths(jax.random.PRNGKey(5), spec, (6, 2))
    pts = jnp.ones((7, 3))
    batched = jax.jit(jax.vmap(lambda m, a: m.robot_distance(pts, a), in_axes=(None, 0)))(model, arcs)
    assert batched.shape == (6, 7)
    np.testing.assert_allclose(batched[2], model.robot_distance(pts, arcs[2]), rtol=1e-5)


def test_save_load_round_trip_with_metadata(tmp_path):
    model = _model()
    save_model(tmp_path / "m", model.params, model.config, SPEC, {"metrics": {"mae": 0.5}})
    loaded = load_model(tmp_path / "m.msgpack")
    assert loaded.config == model.config and loaded.spec == SPEC
    assert loaded.metadata["metrics"] == (("mae", 0.5),)
    pts = jax.random.normal(jax.random.PRNGKey(6), (10, 3))
    np.testing.assert_array_equal(loaded.link_distance(pts, 0.3, 0.2), model.link_distance(pts, 0.3, 0.2))


def test_load_errors_name_the_file(tmp_path):
    with pytest.raises(ModelError, match="not found.*nothere"):
        load_model(tmp_path / "nothere")
    model = _model()
    weights, meta = save_model(tmp_path / "m", model.params, model.config, SPEC, {})
    # Another architecture's metadata next to these weights.
    other = json.loads(meta.read_text())
    other["architecture"]["width"] = 16
    meta.write_text(json.dumps(other))
    with pytest.raises(ModelError, match="m.msgpack"):
        load_model(tmp_path / "m")
    # An expected architecture that differs.
    save_model(tmp_path / "m", model.params, model.config, SPEC, {})
    with pytest.raises(ModelError, match="expected"):
        load_model(tmp_path / "m", expect=ModelConfig(layers=4, width=16))
    # Corrupted bytes.
    weights.write_bytes(weights.read_bytes()[:40])
    with pytest.raises(ModelError, match="corrupted"):
        load_model(tmp_path / "m")
    meta.write_text("{not json")
    with pytest.raises(ModelError, match="corrupted model metadata"):
        load_model(tmp_path / "m")


def test_shipped_model_meets_the_paper_accuracy_on_fresh_robot_configurations():
    """The shipped 4x16 model composed over 4 links, against exact distances."""
    model = load_model()
    assert (model.config.layers, model.config.width) == (4, 16)
    spec = RobotSpec(4)
    arcs = sample_arc_lengths(jax.random.PRNGKey(2024), spec, (8, 4))
    pts = jax.random.uniform(jax.random.PRNGKey(7), (4000, 3), minval=jnp.array([-5.0, -5.0, -1.0]),
                             maxval=jnp.array([5.0, 5.0, 8.0]))
    pred = jax.vmap(model.robot_distance, in_axes=(None, 0))(pts, arcs)
    true = np.asarray(jnp.abs(jax.vmap(robot_signed_distance, in_axes=(None, 0, None))(pts, arcs, spec)))
    err = np.asarray(pred) - true
    near = true < 2.0  # the region where the collision cost acts
    assert near.sum() > 1000
    # Paper Table I, 4 x 16: MAE 0.017 m, MOE 0.002 m.
    assert np.mean(np.abs(err[near])) < 0.017
    assert np.mean(np.maximum(err[near], 0)) < 0.002
    # Where collisions are decided, no over-estimation reaches the 0.05 m safety margin.
    assert np.max(err[true < 0.5]) < 0.05


def test_chord_bounds_enclose_the_exact_distance():
    spec = RobotSpec(1)
    pts = jax.random.uniform(jax.random.PRNGKey(9), (5000, 3), minval=-6.0, maxval=6.0)
    for theta, phi in [(0.0, 0.0), (1.2, 0.4), (2.3, -2.0)]:
        arc = config_to_arc_lengths(jnp.array([theta]), jnp.array([phi]), spec)
        sd = np.asarray(robot_signed_distance(pts, arc, spec))
        lower, upper = map(np.asarray, chord_bounds(pts, theta, phi, spec))
        out = sd > 0
        assert np.all(lower[out] <= sd[out] + 1e-5) and np.all(sd[out] <= upper[out] + 1e-5)


def test_outside_the_training_box_the_link_distance_is_clamped_to_the_chord_bounds():
    model = load_model()
    pts = jax.random.uniform(jax.random.PRNGKey(8), (3000, 3), minval=-9.0, maxval=9.0)
    lo, hi = np.array(model.domain[0]), np.array(model.domain[1])
    outside = np.any((np.asarray(pts) < lo) | (np.asarray(pts) > hi), axis=1)
    assert outside.mean() > 0.5
    inside_model = dataclasses.replace(model, domain=((-100.0,) * 3, (100.0,) * 3))
    for theta, phi in [(0.0, 0.0), (1.2, 0.4), (2.2, -2.0)]:
        pred = np.asarray(model.link_distance(pts, theta, phi))
        raw = np.asarray(inside_model.link_distance(pts, theta, phi))
        lower, upper = map(np.asarray, chord_bounds(pts, theta, phi, model.spec))
        np.testing.assert_allclose(pred[~outside], raw[~outside])
        np.testing.assert_allclose(pred[outside], np.clip(raw, lower, upper)[outside], rtol=1e-6)
        arc = config_to_arc_lengths(jnp.array([theta]), jnp.array([phi]), model.spec)
        true = np.abs(np.asarray(robot_signed_distance(pts, arc, model.spec)))[outside]
        assert np.mean(np.abs(pred[outside] - true) / true) < 0.05


def test_softplus_is_log_one_plus_exp():
    # Against the closed form in float64 (numpy's log1p and exp) over the range a layer meets
    # and beyond; its derivative against the logistic function.
    x = np.linspace(-40.0, 40.0, 400001)
    exact = np.maximum(x, 0.0) + np.log1p(np.exp(-np.abs(x)))
    with jax.enable_x64(True):
        got = np.asarray(softplus(jnp.asarray(x)))
        slope = np.asarray(jax.vmap(jax.grad(softplus))(jnp.asarray(x)))
    assert np.max(np.abs(got - exact)) < 2.5e-7
    assert np.max(np.abs(slope - 1.0 / (1.0 + np.exp(-x)))) < 3e-5
    assert np.max(np.abs(np.asarray(softplus(jnp.asarray(x, jnp.float32))) - exact)) < 2e-6
