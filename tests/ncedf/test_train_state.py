"""A training run stopped after an epoch and resumed from its saved state gives the floats of a run
never stopped; a saved state is only resumed by the run that saved it."""

import jax
import numpy as np
import pytest

from ncedf.data import DatasetConfig, ValidationConfig, load_dataset
from ncedf.model import ModelConfig
from ncedf.robot import RobotSpec
from ncedf.train import TrainConfig, train
from ncedf.train_state import load_state, save_state

SPEC = RobotSpec(1)
MODEL = ModelConfig(layers=3, width=8)
CONFIG = TrainConfig(epochs=3, batch_size=128)  # the cosine schedule: the step count matters
LOSSES = ("distance", "eikonal", "over", "mae", "moe")


class Stopped(Exception):
    pass


@pytest.fixture(scope="module")
def sets(tmp_path_factory):
    cache = tmp_path_factory.mktemp("cache")
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("NCEDF_CACHE", str(cache))
        return (load_dataset(DatasetConfig(n_configs=6, grid=8, n_surface=20), SPEC),
                load_dataset(ValidationConfig(n_configs=4, n_points=64, n_surface=8), SPEC))


def leaves(model):
    return [np.asarray(x) for x in jax.tree_util.tree_leaves(model.params)]


def test_a_stopped_run_resumed_from_its_state_matches_a_run_never_stopped(sets, tmp_path):
    data, val = sets
    whole, whole_history = train(MODEL, CONFIG, data, val, SPEC, progress=False)
    saved = tmp_path / "run.state.msgpack"

    def save_then_stop(row, state):
        save_state(saved, state, "run")
        if state.epoch == 1:
            raise Stopped

    with pytest.raises(Stopped):
        train(MODEL, CONFIG, data, val, SPEC, progress=False, on_epoch=save_then_stop)
    resumed_rows = []
    model, history = train(MODEL, CONFIG, data, val, SPEC, progress=False,
                           on_epoch=lambda row, state: resumed_rows.append(row["epoch"]),
                           resume=lambda template: load_state(saved, template, "run"))
    assert resumed_rows == [2, 3]  # only the epochs left were trained
    assert all(np.array_equal(a, b) for a, b in zip(leaves(model), leaves(whole), strict=True))
    assert [[row[k] for k in LOSSES] for row in history] == [[row[k] for k in LOSSES] for row in whole_history]


def test_a_state_is_resumed_only_with_its_fingerprint(sets, tmp_path):
    data, val = sets
    saved = tmp_path / "run.state.msgpack"
    states = []
    train(MODEL, CONFIG, data, val, SPEC, progress=False, on_epoch=lambda row, state: states.append(state))
    save_state(saved, states[0], "network A")
    assert [p.name for p in tmp_path.iterdir()] == [saved.name]  # written beside, then renamed
    template = states[-1]
    assert load_state(tmp_path / "missing.msgpack", template, "network A") is None
    assert load_state(saved, template, "network B") is None
    back = load_state(saved, template, "network A")
    assert back.epoch == 1 and back.history == states[0].history
    assert np.array_equal(back.key, states[0].key)
    assert jax.tree_util.tree_structure(back.opt_state) == jax.tree_util.tree_structure(states[0].opt_state)
