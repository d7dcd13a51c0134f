"""The presets as a user composes them with ``ncedf`` alone: functions of the robot and the observation,
their metadata round trip, and one-line errors for what makes no sense."""

import json

import numpy as np
import pytest

from ncedf.controller import ControllerConfig, config_from_dict, config_to_dict
from ncedf.presets import PRESETS, Observation, preset
from ncedf.robot import RobotSpec

OBSERVATIONS = (Observation(500), Observation(8, ball_radius=0.7), Observation(0))


@pytest.mark.parametrize("name", sorted(PRESETS))
@pytest.mark.parametrize("links", [4, 7])
def test_a_preset_survives_the_recordings_json_round_trip(name, links):
    for observation in OBSERVATIONS:
        config = preset(name, RobotSpec(links), observation)
        assert config_from_dict(json.loads(json.dumps(config_to_dict(config)))) == config


def test_the_core_holds_the_papers_names_at_the_top_of_the_metadata():
    """Analysis reads ``mppi.samples`` / ``mppi.horizon`` / ``mppi.safety_margin`` from recordings of every age."""
    meta = config_to_dict(preset("ours", RobotSpec(4), Observation(8, ball_radius=0.7)))
    assert (meta["samples"], meta["horizon"]) == (1000, 12)
    assert meta["safety_margin"] == pytest.approx(0.05 + 0.7)


def test_ours_closes_surface_clouds_and_races_among_balls():
    spec = RobotSpec(5)
    surfaces, balls = preset("ours", spec, Observation(500)), preset("ours", spec, Observation(8, ball_radius=0.7))
    assert surfaces.model is not None and surfaces.recovery is not None and balls.model is None
    assert balls.safety.sweep_first and not surfaces.safety.sweep_first
    # The observation alone decides: the capacity follows the cloud, nothing else changes with its size.
    bigger = preset("ours", spec, Observation(5000))
    assert bigger.mppi.max_points >= 5000
    assert ControllerConfig(**{**bigger.__dict__, "mppi": surfaces.mppi}) == surfaces


@pytest.mark.parametrize("bad, message", [
    (dict(n_points=-1), "n_points"), (dict(n_points=2.5), "n_points"), (dict(n_points=5, ball_radius=-0.1), "ball_radius"),
    (dict(n_points=5, ball_radius=float("nan")), "ball_radius")])
def test_a_bad_observation_is_named(bad, message):
    with pytest.raises(ValueError, match=message):
        Observation(**bad)


def test_an_observation_takes_numpy_counts():
    assert preset("paper", RobotSpec(4), Observation(np.int64(300))).mppi.max_points == 512
