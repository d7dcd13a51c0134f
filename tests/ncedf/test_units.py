"""Robots of other sizes: a robot and its world scaled together give scaled distances and motions.

Closed forms: the exact link distance and the kinematics of a link scaled by s are the paper
link's scaled by s. The controller and the judge work in the robot's units (``ncedf.units``): at a
power-of-two scale every scaled input is exact in floating point, so their outputs must be the
paper robot's scaled exactly.
"""

import jax
import numpy as np
import pytest

from ncedf.controller import Controller, ControllerConfig
from ncedf.geometry import link_signed_distance
from ncedf.model import load_model, save_model
from ncedf.mppi import MPPIConfig
from ncedf.robot import RobotSpec, forward_kinematics, sample_arc_lengths
from ncedf.shapes import make_shape
from ncedf.units import REFERENCE_LENGTH, to_reference, unit
from scenarios.judge import judge_step
from scenarios.world import Box, MovingSphere, World

PAPER = RobotSpec(3)
SMALL = RobotSpec(3, 0.1, 0.01, 0.08, 0.12)  # the paper's robot at 1/20


def test_a_scaled_link_has_the_scaled_exact_distance_and_kinematics():
    key = jax.random.PRNGKey(0)
    points = jax.random.uniform(key, (200, 3), minval=-2.5, maxval=3.0)
    for theta, phi in ((0.0, 0.0), (0.7, -2.0), (2.1, 1.3)):
        full = link_signed_distance(points, theta, phi, RobotSpec(1))
        small = link_signed_distance(0.05 * points, theta, phi, RobotSpec(1, 0.1, 0.01, 0.08, 0.12))
        np.testing.assert_allclose(small, 0.05 * full, rtol=1e-4, atol=1e-7)
    arcs = sample_arc_lengths(key, PAPER, (5, PAPER.n_links))
    full, small = forward_kinematics(arcs, PAPER), forward_kinematics(0.05 * arcs, SMALL)
    np.testing.assert_allclose(small[..., :3, :3], full[..., :3, :3], atol=2e-5)
    np.testing.assert_allclose(small[..., :3, 3], 0.05 * full[..., :3, 3], atol=1e-6)


def test_the_reference_robot_is_the_paper_link_and_scaling_round_trips():
    assert to_reference(SMALL) == PAPER and unit(SMALL) == pytest.approx(0.05)
    assert to_reference(PAPER) == PAPER and unit(PAPER) == 1.0
    assert SMALL.scaled(20.0).scaled(0.05) == SMALL
    assert to_reference(RobotSpec(2, 3.0, 0.3, 2.4, 3.6)).length == REFERENCE_LENGTH


@pytest.mark.parametrize("fields, words", [
    (dict(length=2.0, radius=0.2, l_min=0.1, l_max=3.9), "bend radius"),
    (dict(length=2.0, radius=0.2, l_min=2.1, l_max=2.4), "l_min < length < l_max"),
    (dict(length=0.1, radius=-0.01, l_min=0.08, l_max=0.12), "radius must be > 0"),
])
def test_a_robot_that_makes_no_sense_is_named(fields, words):
    with pytest.raises(ValueError, match=words):
        RobotSpec(1, **fields)


def test_the_model_rescaled_scales_its_distances(tmp_path):
    model = load_model()
    small_spec = RobotSpec(1, 1.0, 0.1, 0.8, 1.2)  # half size: every scaled input is exact
    save_model(tmp_path / "half", model.params, model.config, small_spec, {},
               tuple(tuple(0.5 * v for v in corner) for corner in model.domain))
    half = load_model(tmp_path / "half")
    assert half.spec == small_spec and half.rescaled(RobotSpec(1)).spec == RobotSpec(1)
    points = jax.random.uniform(jax.random.PRNGKey(1), (64, 3), minval=-4.0, maxval=4.0)
    np.testing.assert_array_equal(half.link_distance(0.5 * points, 0.9, 0.4),
                                  0.5 * model.link_distance(points, 0.9, 0.4))


def _first_actions(spec, factor, goal, points):
    config = ControllerConfig(MPPIConfig(samples=16, horizon=4, max_points=256))
    controller = Controller(spec, make_shape("spheres", spec), config)
    state = controller.init(jax.random.PRNGKey(3))
    arc = np.asarray(spec.straight_state(), np.float32)
    actions, plans = [], []
    for _ in range(3):
        action, state, info = controller.step(state, arc, factor * goal, factor * points)
        arc = np.asarray(arc + np.asarray(action) * config.mppi.dt, np.float32)
        actions.append(np.asarray(action))
        plans.append(np.asarray(info.plan))
    return np.stack(actions), np.stack(plans)


def test_the_controller_of_a_half_size_robot_moves_it_at_half_the_rates():
    goal = np.array([2.0, 1.0, 4.5], np.float32)
    points = np.asarray(jax.random.uniform(jax.random.PRNGKey(2), (40, 3), minval=-3.0, maxval=3.0) + 3.0, np.float32)
    full_actions, full_plans = _first_actions(PAPER, 1.0, goal, points)
    half_actions, half_plans = _first_actions(PAPER.scaled(0.5), 0.5, goal, points)
    assert np.abs(full_actions).max() > 0.01
    np.testing.assert_array_equal(half_actions, 0.5 * full_actions)
    np.testing.assert_array_equal(half_plans, 0.5 * full_plans)


def test_the_judge_of_a_scaled_robot_and_world_scales_its_distances_and_finds_the_same_collision():
    world = World(spheres=(MovingSphere((1.2, 0.0, 4.0), 0.3, (0.0, 0.5, 0.0), 2.0),),
                  boxes=(Box((1.0, 0.0, 2.5), (0.4, 2.0, 0.6)),))
    arc0 = np.asarray(PAPER.straight_state(), np.float64)
    bend = np.array([[1.75, 2.125, 2.125], [2.0, 2.0, 2.0], [2.0, 2.0, 2.0]])  # towards the box
    for factor in (0.05, 0.5):
        spec, small_world = PAPER.scaled(factor), world.scaled(factor)
        for k in range(4):
            a0, a1 = arc0 + (bend - arc0) * k / 4, arc0 + (bend - arc0) * (k + 1) / 4
            full = judge_step(world, PAPER, a0, a1, 0.05 * k, 0.05)
            small = judge_step(small_world, spec, factor * a0, factor * a1, 0.05 * k, 0.05)
            assert small.substeps == full.substeps
            assert small.min_distance == pytest.approx(factor * full.min_distance, rel=1e-4, abs=1e-7 * factor)
            assert (small.first_collision_time is None) == (full.first_collision_time is None)
    assert full.first_collision_time is not None  # the last step bends link 1 into the box
