"""Training: loss terms in closed form, clipping before the update, a short run learns."""

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

from ncedf.data import DatasetConfig, ValidationConfig, load_dataset
from ncedf.model import ModelConfig
from ncedf.robot import RobotSpec
from ncedf.train import TrainConfig, epoch_order, loss_terms, make_optimizer, main, train, training_arrays

SPEC = RobotSpec(1)


@pytest.fixture(autouse=True)
def _cache(tmp_path, monkeypatch):
    monkeypatch.setenv("NCEDF_CACHE", str(tmp_path))


def _linear_params(w, b):
    """A one-layer (linear) network: out = w . x + b."""
    return {"params": {"Dense_0": {"kernel": jnp.asarray(w, jnp.float32)[:, None],
                                   "bias": jnp.array([b], jnp.float32)}}}


def test_loss_terms_match_closed_forms_on_a_linear_network():
    cfg = ModelConfig(layers=1, width=1, encoding="bending-plane", output="distance")
    # Gradient w.r.t. the point (last three inputs) is (0, 0.6, 0.8) scaled by 2: norm 2.
    params = _linear_params([5.0, 0.0, 1.2, 1.6], 0.1)
    x = jnp.array([[0.1, 1.0, 1.0, 1.0], [0.2, 0.0, 0.0, 0.0]])
    y = jnp.array([3.0, 0.5])
    pred = np.array([0.5 + 1.2 + 1.6 + 0.1, 1.0 + 0.1])
    terms = loss_terms(params, cfg, x, y)
    np.testing.assert_allclose(terms["distance"], np.mean((pred - y) ** 2), rtol=1e-5)
    np.testing.assert_allclose(terms["eikonal"], (2.0 - 1.0) ** 2, rtol=1e-5)
    np.testing.assert_allclose(terms["over"], np.mean(np.maximum(pred - y, 0) ** 2), rtol=1e-5)


def test_signed_abs_over_estimation_compares_the_absolute_output_with_the_distance():
    cfg = ModelConfig(layers=1, width=1, output="signed-abs")
    params = _linear_params([0.0, 0.0, 0.0, 0.0], -0.3)  # raw output -0.3 everywhere
    x = jnp.zeros((2, 4))
    y = jnp.array([-0.1, 0.5])  # inside at depth 0.1; outside at 0.5
    terms = loss_terms(params, cfg, x, y)
    np.testing.assert_allclose(terms["distance"], np.mean([(-0.3 + 0.1) ** 2, (-0.3 - 0.5) ** 2]), rtol=1e-5)
    np.testing.assert_allclose(terms["over"], np.mean([(0.3 - 0.1) ** 2, 0.0]), rtol=1e-5)


def test_near_weight_reweights_near_samples():
    cfg = ModelConfig(layers=1, width=1, output="distance")
    params = _linear_params([0.0, 0.0, 0.0, 0.0], 0.0)
    x = jnp.zeros((2, 4))
    y = jnp.array([0.1, 1.0])  # one near-field, one far sample; squared errors 0.01 and 1
    terms = loss_terms(params, cfg, x, y, near_weight=3.0)
    np.testing.assert_allclose(terms["distance"], (3.0 * 0.01 + 1.0) / 2.0 / (4.0 / 2.0), rtol=1e-5)


def test_gradient_is_clipped_before_the_adam_update():
    """Adam is scale-invariant on its first step only; clipping makes two histories equal."""
    cfg = TrainConfig(epochs=1, schedule="constant", weight_decay=0.0, clip_norm=1.0)
    params = {"w": jnp.zeros(3)}
    g = jnp.array([3.0, -4.0, 12.0])

    def second_update(scale):
        opt = make_optimizer(cfg, 10)
        state = opt.init(params)
        _, state = opt.update({"w": scale * g}, state, params)
        update, _ = opt.update({"w": 0.05 * g}, state, params)
        return update["w"]

    # |g| = 13: both first gradients (norms 1.3 and 13) are clipped to norm 1.
    np.testing.assert_allclose(second_update(0.1), second_update(1.0), rtol=1e-6)
    unclipped = optax.adam(cfg.learning_rate)
    s1, s2 = unclipped.init(params), unclipped.init(params)
    _, s1 = unclipped.update({"w": 0.1 * g}, s1)
    _, s2 = unclipped.update({"w": 1.0 * g}, s2)
    u1, _ = unclipped.update({"w": 0.05 * g}, s1)
    u2, _ = unclipped.update({"w": 0.05 * g}, s2)
    assert not np.allclose(u1["w"], u2["w"], rtol=1e-3)


def test_signed_targets_are_negative_inside():
    data = load_dataset(DatasetConfig(n_configs=3, grid=12, n_surface=8), SPEC)
    _, y = training_arrays(data, ModelConfig(output="signed-abs"))
    k = data.points.shape[1]
    np.testing.assert_allclose(y[: 3 * k], np.where(data.inside, -data.distances, data.distances).ravel())
    np.testing.assert_array_equal(y[3 * k:], 0.0)
    assert data.inside.any()


def test_an_epochs_order_draws_each_sample_at_most_once_and_the_key_decides_it():
    order = epoch_order(jax.random.PRNGKey(3), 1000, 64)
    assert order.shape == (15, 64) and order.dtype == np.int32
    assert len(np.unique(order)) == order.size and order.min() >= 0 and order.max() < 1000
    np.testing.assert_array_equal(order, epoch_order(jax.random.PRNGKey(3), 1000, 64))
    assert not np.array_equal(order, epoch_order(jax.random.PRNGKey(4), 1000, 64))
    full = epoch_order(jax.random.PRNGKey(5), 1024, 64)
    np.testing.assert_array_equal(np.sort(full.ravel()), np.arange(1024))


def test_short_training_run_reduces_validation_error():
    data = load_dataset(DatasetConfig(n_configs=20, grid=10, n_surface=100), SPEC)
    val = load_dataset(ValidationConfig(n_configs=10, n_points=256, n_surface=16), SPEC)
    cfg = TrainConfig(epochs=4, batch_size=128)
    model, history = train(ModelConfig(layers=3, width=16), cfg, data, val, SPEC, progress=False)
    assert len(history) == 4
    # Far better than the best constant prediction (the median label).
    constant_mae = np.mean(np.abs(val.distances - np.median(val.distances)))
    assert history[-1]["mae"] < 0.3 * constant_mae
    assert all(np.isfinite(row["distance"]) for row in history)
    assert model.link_distance(jnp.zeros((2, 3)), 0.1, 0.2).shape == (2,)


@pytest.mark.parametrize("option, value, message", [
    ("--epochs", "0", "must be >= 1, got 0"),
    ("--configs", "0", "must be >= 1, got 0"),
    ("--near", "-1", "must be >= 0, got -1"),
    ("--batch-size", "2.5", "not an integer: '2.5'"),
])
def test_cli_names_the_option_of_a_bad_count_in_one_line(capsys, tmp_path, option, value, message):
    with pytest.raises(SystemExit) as stop:
        main([option, value, "--out", str(tmp_path / "m")])
    assert stop.value.code == 2
    assert capsys.readouterr().err.strip() == f"python -m ncedf.train: error: argument {option}: {message}"
    assert not list(tmp_path.iterdir())


@pytest.mark.parametrize("option, value, message", [
    ("--lambda-eikonal", "nan", "TrainConfig.lambda_eikonal must be finite, got nan"),
    ("--lr", "inf", "TrainConfig.learning_rate must be finite, got inf"),
    ("--lambda-over", "-1", "TrainConfig.lambda_over must be >= 0, got -1.0"),
])
def test_cli_rejects_bad_values_with_one_line(capsys, tmp_path, option, value, message):
    assert main([option, value, "--out", str(tmp_path / "m")]) == 2
    assert capsys.readouterr().err.strip() == f"error: {message}"
    assert not list(tmp_path.iterdir())


def test_cli_names_weights_it_cannot_write_before_training(capsys, tmp_path, monkeypatch):
    """A folder where the weights would go, even with --overwrite, and a folder that refuses files."""
    (tmp_path / "m.msgpack").mkdir()
    assert main(["--overwrite", "--out", str(tmp_path / "m")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "m.msgpack is a folder" in err[0]
    trained = []
    monkeypatch.setattr("ncedf.train.train_links", lambda *a, **k: trained.append(1))
    assert main(["--out", "/proc/m"]) == 2  # /proc takes no new files, even as root
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: cannot write weights to /proc") and not trained


def test_cli_trains_saves_a_loadable_model_and_records_the_run(tmp_path):
    from ncedf.model import load_model
    from recorder import load_run

    out, rec = tmp_path / "m", tmp_path / "train-run"
    argv = ["--layers", "2", "--width", "8", "--epochs", "2", "--batch-size", "128", "--configs", "8", "--grid", "8",
            "--surface", "32", "--val-configs", "4", "--val-points", "256", "--out", str(out), "--record", str(rec)]
    assert main(argv) == 0
    model = load_model(out)
    meta = model.metadata
    assert dict(meta["architecture"])["layers"] == 2 and dict(meta["dataset"])["n_configs"] == 8
    run = load_run(f"{rec}.mcap")
    assert list(run.metrics["step"]) == [1, 2]
    assert run.metrics["mae"].iloc[-1] == pytest.approx(dict(meta["metrics"])["mae"], rel=1e-6)
    assert run.outcome["outcome"] == "success"
    # Neither the weights nor the recording are overwritten silently.
    assert main(argv) == 2
    assert main(argv + ["--record", str(tmp_path / "other")]) == 2


def test_cli_names_a_robot_that_makes_no_sense_before_training(capsys, tmp_path):
    argv = ["--radius", "0.5", "--arc-min", "0.1", "--arc-max", "3.9", "--out", str(tmp_path / "m")]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: radius 0.5 m is not below the bend radius")
    assert main(["--length", "0.1", "--out", str(tmp_path / "m")]) == 2  # arc limits 1.6-2.4 do not hold 0.1
    assert "l_min < length < l_max" in capsys.readouterr().err
    assert not list(tmp_path.iterdir())


def test_cli_trains_a_small_robot_and_its_weights_name_it(tmp_path):
    from ncedf.model import load_model
    from ncedf.train import evaluate_model

    out = tmp_path / "small"
    argv = ["--length", "0.1", "--radius", "0.01", "--arc-min", "0.08", "--arc-max", "0.12", "--layers", "2",
            "--width", "8", "--epochs", "1", "--configs", "4", "--grid", "6", "--surface", "16",
            "--val-configs", "4", "--val-points", "512", "--out", str(out)]
    assert main(argv) == 0
    model = load_model(out)
    assert model.spec == RobotSpec(1, 0.1, 0.01, 0.08, 0.12)
    np.testing.assert_allclose(model.domain, [[-0.125, -0.125, -0.05], [0.125, 0.125, 0.15]])
    metrics = dict(model.metadata["metrics"])
    # validated on the small link's own exact distances, with a near field in proportion (at 0.5 m it would be all)
    val = load_dataset(ValidationConfig(4, 512, box_min=model.domain[0], box_max=model.domain[1]), model.spec)
    assert evaluate_model(model, val)["mae"] == pytest.approx(metrics["mae"], rel=1e-5)
    assert 0 < metrics["near_fraction"] < 0.5


def test_cli_trains_a_tapered_robot_a_network_per_link(tmp_path):
    from ncedf.model import load_model
    from ncedf.train import evaluate_model

    out = tmp_path / "tapered"
    argv = ["--radius", "0.25", "0.15", "--layers", "2", "--width", "8", "--epochs", "1", "--configs", "4",
            "--grid", "6", "--surface", "16", "--val-configs", "4", "--val-points", "512", "--out", str(out)]
    assert main(argv) == 0
    model = load_model(out)
    assert model.spec == RobotSpec(2, radius=(0.25, 0.15))
    per_link = [dict(m) for m in model.metadata["link_metrics"]]
    for link, recorded in zip(model.links(), per_link):  # each network validated on its own link's exact distances
        val = load_dataset(ValidationConfig(4, 512, box_min=model.domain[0], box_max=model.domain[1]), link.spec)
        assert evaluate_model(link, val)["mae"] == pytest.approx(recorded["mae"], rel=1e-5)
    assert dict(model.metadata["metrics"])["mae"] == max(m["mae"] for m in per_link)
    assert len(model.metadata["history"]) == 2


def test_evaluate_names_the_option_of_a_bad_count_in_one_line(capsys):
    from ncedf.evaluate import main as evaluate

    with pytest.raises(SystemExit) as stop:
        evaluate(["--points", "0"])
    assert stop.value.code == 2
    assert capsys.readouterr().err.strip() == "python -m ncedf.evaluate: error: argument --points: must be >= 1, got 0"
