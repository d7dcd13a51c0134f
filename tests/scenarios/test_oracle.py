"""Tests of scenarios.oracle against independent truths.

Truths: a sphere that reaches the robot's base disk within the first step
(every configuration contains that disk, so every motion collides); the exact
distance of scenarios.world at each state of a found motion; the straight
robot's own collision where the found motion escapes; the control set's
bounds and zero sums on the found motion's steps; a dense grid over the
control set for the closest approach within one step.
"""

from __future__ import annotations

import jax
import numpy as np
import pytest

from ncedf.sampling import release_controls
from ncedf.robot import RobotSpec, end_effector_pose, forward_kinematics, validate_state
from scenarios.oracle import OracleConfig, closest_approach, plan_reach
from scenarios.truth import true_min_distance
from scenarios.world import Box, MovingSphere, World

SPEC = RobotSpec(2)
DT = 0.05
SMALL = OracleConfig(starts=8, iterations=150)
#: A goal the two-link tip (straight at (0, 0, 4)) reaches by bending towards +x.
GOAL = (1.5, 0.0, 3.3)
TOLERANCE = 0.2


def test_sphere_through_the_base_within_one_step_leaves_no_motion():
    # gap 0.05 m to the base disk at t = 0, closing at 2 m/s: overlap before t = dt
    world = World(spheres=(MovingSphere((0.0, 0.0, -0.55), 0.5, (0.0, 0.0, 2.0)),))
    result = plan_reach(world, SPEC, GOAL, TOLERANCE, [4, 8], DT, jax.random.PRNGKey(0), SMALL)
    assert result.reach_step is None and result.arcs is None and np.isnan(result.min_distance)
    free = plan_reach(World(), SPEC, GOAL, TOLERANCE, [4, 8], DT, jax.random.PRNGKey(0), SMALL)
    assert free.reach_step is not None and free.min_distance == np.inf, "without the sphere the goal is reached"


def test_found_motion_escapes_a_sphere_that_hits_the_still_robot():
    # a sphere coming at the straight robot's upper link from -x at 1.5 m/s
    world = World(spheres=(MovingSphere((-1.4, 0.0, 3.0), 0.5, (1.5, 0.0, 0.0)),))
    straight = np.asarray(SPEC.straight_state(), np.float64)
    still = [true_min_distance(world, SPEC, straight, k * DT) for k in range(12)]
    assert min(still) < 0, "the still robot must be hit for this test to mean anything"

    result = plan_reach(world, SPEC, GOAL, TOLERANCE, [6, 10], DT, jax.random.PRNGKey(1), SMALL)
    assert result.reach_step is not None and result.horizon in (6, 10)
    arcs = result.arcs
    assert arcs.shape == (result.reach_step + 1, SPEC.n_links, 3)
    for k, arc in enumerate(arcs):
        validate_state(arc, SPEC)
        assert true_min_distance(world, SPEC, arc, k * DT) >= result.min_distance - 1e-6 >= -1e-6
    tip = np.asarray(end_effector_pose(arcs[-1].astype(np.float32), SPEC))[:3, 3]
    assert np.linalg.norm(tip - np.asarray(GOAL)) <= TOLERANCE + 1e-5
    earlier = [np.linalg.norm(np.asarray(end_effector_pose(a.astype(np.float32), SPEC))[:3, 3] - GOAL)
               for a in arcs[:-1]]
    assert min(earlier, default=np.inf) > TOLERANCE, "reach_step must be the first state within the tolerance"
    rates = np.diff(arcs, axis=0) / DT  # (T, M, 3)
    np.testing.assert_allclose(rates.sum(-1), 0.0, atol=1e-4)
    assert np.abs(rates).max() <= 2 * SMALL.control_bound + 1e-4


def test_closest_approach_matches_a_dense_grid_over_one_step():
    # one step from the straight robot reaches exactly straight + dt u, u in the control set: a grid over
    # the two links' four free rates gives the true minimum to within its spacing
    axis = np.linspace(-SMALL.control_bound, SMALL.control_bound, 25)
    free = np.stack(np.meshgrid(axis, axis, axis, axis, indexing="ij"), -1).reshape(-1, SPEC.n_links, 2)
    arcs = SPEC.straight_state()[None] + DT * release_controls(free, SMALL.control_bound)
    tips = np.asarray(forward_kinematics(arcs, SPEC))[:, -1, :3, 3]
    grid = np.linalg.norm(tips - np.asarray(GOAL), axis=-1).min()
    # the closest state has every free rate at its bound, which the rates b tanh z only approach: 400
    # iterations come within 0.3 mm of it (150: 1.2 mm)
    config = OracleConfig(starts=8)
    one = closest_approach(SPEC, GOAL, 1, DT, jax.random.PRNGKey(0), config)
    assert grid - 2e-3 <= one <= grid + 5e-4
    two = closest_approach(SPEC, GOAL, 2, DT, jax.random.PRNGKey(0), config)
    assert two < one - 0.05, "a second step must come closer"
    assert closest_approach(SPEC, GOAL, 8, DT, jax.random.PRNGKey(0), config) <= TOLERANCE


def test_bad_input_is_named():
    with pytest.raises(ValueError, match="starts"):
        OracleConfig(starts=0)
    with pytest.raises(ValueError, match="softness"):
        OracleConfig(softness=0.0)
    boxed = World(boxes=(Box((3.0, 0.0, 1.0), (1.0, 1.0, 1.0)),))
    with pytest.raises(ValueError, match="static obstacles"):
        plan_reach(boxed, SPEC, GOAL, TOLERANCE, [4], DT, jax.random.PRNGKey(0), SMALL)
    with pytest.raises(ValueError, match="position goal"):
        plan_reach(World(), SPEC, np.eye(4), TOLERANCE, [4], DT, jax.random.PRNGKey(0), SMALL)
    with pytest.raises(ValueError, match="horizons"):
        plan_reach(World(), SPEC, GOAL, TOLERANCE, [0], DT, jax.random.PRNGKey(0), SMALL)
    with pytest.raises(ValueError, match="steps"):
        closest_approach(SPEC, GOAL, 0, DT, jax.random.PRNGKey(0), SMALL)
    with pytest.raises(ValueError, match="position goal"):
        closest_approach(SPEC, np.eye(4), 3, DT, jax.random.PRNGKey(0), SMALL)
