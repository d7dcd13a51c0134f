"""The presets as a user composes them with ``ncedf`` alone: functions of the robot and the observation,
their metadata round trip, and one-line errors for what makes no sense."""

import dataclasses
import json

import numpy as np
import pytest

from ncedf.broad_phase import BroadPhase
from ncedf.controller import config_from_dict, config_to_dict
from ncedf.grid_model import GridModel
from ncedf.guide import Guide
from ncedf.obstacle_model import ConvexModel
from ncedf.presets import BALLS_MARGIN, PRESETS, Observation, observe, ours, preset
from ncedf.robot import RobotSpec
from solids import ported_wall, solid_wall

OBSERVATIONS = (Observation(500), Observation(8, ball_radius=0.7), Observation(0), Observation(500, convex=False))


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
    assert meta["safety_margin"] == pytest.approx(BALLS_MARGIN + 0.7)  # the balls' radius on top of the margin


def test_only_the_capacity_follows_the_size_of_the_cloud():
    spec = RobotSpec(5)
    small, big = preset("ours", spec, Observation(500)), preset("ours", spec, Observation(5000))
    assert big.mppi.max_points >= 5000 > small.mppi.max_points
    assert dataclasses.replace(big, mppi=small.mppi) == small


def test_bad_metadata_is_named():
    meta = config_to_dict(preset("ours", RobotSpec(4), Observation(10)))
    with pytest.raises(ValueError, match="unknown core settings"):
        config_from_dict({**meta, "wobble": 1})
    with pytest.raises(ValueError, match="unknown safety settings"):
        config_from_dict({**meta, "safety": {**meta["safety"], "margin": 0.1}})
    with pytest.raises(ValueError, match="temperature type"):
        config_from_dict({**meta, "temperature": {"target": 0.02}})
    # A stage the metadata does not name takes its default.
    assert config_from_dict({k: v for k, v in meta.items() if k != "broad_phase"}) == preset(
        "ours", RobotSpec(4), Observation(10))


def test_recordings_made_with_the_broad_phases_removed_selection_fields_read_back_or_are_refused():
    """Recordings made before 2026-12-07 name the broad phase's selection and its second one's sizes:
    with the selection every preset used they are today's controller; with the removed one, refused."""
    config = preset("ours", RobotSpec(4), Observation(10))
    meta = config_to_dict(config)
    then = {**meta["broad_phase"], "selection": "mean", "groups": 32, "group_size": 16}
    assert config_from_dict({**meta, "broad_phase": then}) == config
    with pytest.raises(ValueError, match="selection 'state'.*removed"):
        config_from_dict({**meta, "broad_phase": {**then, "selection": "state"}})
    flat = {"samples": 8, "temperature": 0.02}
    assert config_from_dict({**flat, "selection": "mean", "groups": 8}).broad_phase == BroadPhase(k2=12,
                                                                                                 capsule_segments=2)
    with pytest.raises(ValueError, match="selection='state'.*removed"):
        config_from_dict({**flat, "selection": "state"})


def test_recordings_made_before_the_plans_grew_plan_every_route_alike():
    """A route recovery whose metadata names no growth (recordings before 2026-12-07) reads back with
    growth 1: every plan with the first one's settings, as it ran."""
    config = preset("ours", RobotSpec(4), Observation(10))
    meta = config_to_dict(config)
    assert meta["recovery"]["growth"] == config.recovery.growth > 1
    then = {k: v for k, v in meta["recovery"].items() if k != "growth"}
    assert config_from_dict({**meta, "recovery": then}).recovery == dataclasses.replace(config.recovery, growth=1.0)


@pytest.mark.parametrize("name", ["paper", "release"])
def test_flat_settings_of_old_recordings_are_the_presets_of_today(name):
    """The flat settings the release and paper presets wrote before the stages (their non-default fields),
    with the broad phase's sizes of then (12 pairs per state, 2 capsules per link)."""
    flat = {"samples": 800, "horizon": 20, "max_points": 512}
    if name == "release":
        flat.update(covariance=0.1, noise_clip=0.5, w_goal_terminal=22.0, w_coll_terminal=1.1, w_perturbation=0.1)
    then = dataclasses.replace(preset(name, RobotSpec(4), Observation(500)), broad_phase=BroadPhase(k2=12, capsule_segments=2))
    assert config_from_dict(flat) == then
    with pytest.raises(ValueError, match="sweep_first"):
        config_from_dict({**flat, "sweep_first": True})
    with pytest.raises(ValueError, match="RouteRecovery.route .*no field wobble"):  # one line, not a TypeError
        config_from_dict({**flat, "route_after": 30, "route": {"wobble": 1}})


@pytest.mark.parametrize("bad, message", [
    (dict(n_points=-1), "n_points"), (dict(n_points=2.5), "n_points"), (dict(n_points=5, ball_radius=-0.1), "ball_radius"),
    (dict(n_points=5, ball_radius=float("nan")), "ball_radius")])
def test_a_bad_observation_is_named(bad, message):
    with pytest.raises(ValueError, match=message):
        Observation(**bad)


def test_an_observation_takes_numpy_counts():
    assert preset("paper", RobotSpec(4), Observation(np.int64(300))).mppi.max_points == 512


def test_observe_tells_a_cloud_with_a_concave_still_cluster():
    """Two observations of a ported wall and of a solid one (points still): the ported one is not convex,
    and ours then closes it on a grid, guides the goal cost through its free space and plans routes round
    the grid; the solid one gets the convex model."""
    ported, solid = ported_wall(spacing=(0.125, 0.5, 0.5)), solid_wall(spacing=(0.125, 0.5, 0.5))
    assert not observe(ported, ported).convex and observe(solid, solid).convex
    assert observe(ported, ported).gap > 0
    spec = RobotSpec(4)
    concave, convex = ours(spec, observe(ported, ported)), ours(spec, observe(solid, solid))
    assert isinstance(concave.model, GridModel) and isinstance(concave.guide, Guide) and concave.recovery
    assert isinstance(convex.model, ConvexModel) and convex.guide is None
    # The same points moving (a ported obstacle passing by) are closed whole: nothing is left out.
    assert observe(ported, ported + np.float32([0.0, 0.1, 0.0])).convex
    with pytest.raises(ValueError, match="same rows"):
        observe(ported, solid)


def test_a_recorded_convex_model_without_its_kind_is_read_as_one():
    """Recordings made while the convex model was the only obstacle model name no kind for it."""
    meta = config_to_dict(preset("ours", RobotSpec(4), Observation(500)))
    assert meta["model"].pop("type") == "ConvexModel"
    assert config_from_dict(meta) == preset("ours", RobotSpec(4), Observation(500))
