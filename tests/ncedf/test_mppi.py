"""MPPI controller: validation, projection, determinism, compilation, closed loop."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from ncedf.broad_phase import BroadPhase, rollout_min_distances_broad, rollout_min_distances_brute
from ncedf.controller import Controller, ControllerConfig
from ncedf.geometry import robot_signed_distance
from ncedf.mppi import MPPIConfig, mppi_step
from ncedf.safety import SafetyFilter, limit_to_state_bounds
from ncedf.sampling import Sampling, project_controls
from ncedf.temperature import EffectiveSampleSize, Fixed, StallEscape
from ncedf.robot import InvalidStateError, RobotSpec, end_effector_pose, project_state, sample_arc_lengths
from ncedf.shapes import make_shape
from scenarios.observe import make_observer
from scenarios.world import Box, World

SPEC = RobotSpec(4)
SMALL = ControllerConfig(MPPIConfig(samples=64, horizon=10, max_points=64))


@pytest.fixture(scope="module")
def exact_mppi():
    # Cheap to compile; the exact representation is exercised in the broad-phase test.
    return Controller(SPEC, make_shape("spheres:2", SPEC), SMALL)


@pytest.mark.parametrize(
    "stage, field, value",
    [(MPPIConfig, "samples", 0), (MPPIConfig, "horizon", -1), (MPPIConfig, "covariance", float("nan")),
     (MPPIConfig, "alpha_u", 0.0), (MPPIConfig, "alpha_u", 1.5), (MPPIConfig, "w_goal", -1.0),
     (MPPIConfig, "control_bound", -0.3), (MPPIConfig, "dt", float("inf")), (MPPIConfig, "samples", 2.5),
     (MPPIConfig, "max_points", 0), (MPPIConfig, "goal_reach", 1), (MPPIConfig, "progress", 0.0),
     (MPPIConfig, "first_iterations", 0),
     (Fixed, "value", 0.0), (EffectiveSampleSize, "target", 0.0), (EffectiveSampleSize, "target", 1.5),
     (EffectiveSampleSize, "escape", 30), (StallEscape, "after", 0), (StallEscape, "target", 2.0),
     (Sampling, "kind", "nearest"), (Sampling, "smoothing", 1.0), (Sampling, "clip", 0.0),
     (Sampling, "unclipped", "yes"), (SafetyFilter, "substeps", 0), (SafetyFilter, "sweep_first", 1),
     (BroadPhase, "k1", 0), (BroadPhase, "k2", 1.5), (BroadPhase, "capsule_segments", 0)],
)
def test_bad_config_values_are_rejected(stage, field, value):
    with pytest.raises(ValueError, match=f"{stage.__name__}.{field}"):
        stage(**{field: value})


@pytest.mark.parametrize("stage, value", [("temperature", None), ("sampling", "release"), ("safety", True),
                                          ("model", 1.0), ("mppi", None)])
def test_a_stage_of_the_wrong_kind_is_named(stage, value):
    with pytest.raises(ValueError, match=f"ControllerConfig.{stage}"):
        ControllerConfig(**{stage: value})


def test_unknown_representation():
    with pytest.raises(ValueError, match="unknown representation"):
        make_shape("voxels", SPEC)


def test_bad_inputs_give_clear_errors(exact_mppi):
    st = exact_mppi.init(jax.random.PRNGKey(0))
    arc = np.asarray(SPEC.straight_state())
    goal = np.array([1.0, 0.0, 7.0])
    bad = arc.copy()
    bad[1, 2] = np.nan
    with pytest.raises(InvalidStateError, match="NaN"):
        exact_mppi.step(st, bad, goal, None)
    with pytest.raises(InvalidStateError, match="outside the limits"):
        exact_mppi.step(st, arc + np.array([0.5, -0.25, -0.25]), goal, None)
    with pytest.raises(ValueError, match="shape"):
        exact_mppi.step(st, arc[:2], goal, None)
    pts = np.ones((5, 3))
    pts[3, 1] = np.nan
    with pytest.raises(ValueError, match="NaN or inf.*row 3"):
        exact_mppi.step(st, arc, goal, pts)
    with pytest.raises(ValueError, match="max_points"):
        exact_mppi.step(st, arc, goal, np.ones((65, 3)))
    with pytest.raises(ValueError, match="goal"):
        exact_mppi.step(st, arc, np.array([1.0, np.nan, 0.0]), None)
    with pytest.raises(ValueError, match="goal"):
        exact_mppi.step(st, arc, np.zeros(2), None)
    with pytest.raises(ValueError, match="links"):
        Controller(RobotSpec(3), make_shape("exact", SPEC), SMALL)


def test_projection_keeps_zero_sum_and_bound():
    u = 3.0 * jax.random.normal(jax.random.PRNGKey(1), (500, 4, 3))
    p = project_controls(u, 0.3)
    np.testing.assert_allclose(p.sum(-1), 0.0, atol=1e-5)  # float32 rounding of inputs ~10
    assert float(jnp.abs(p).max()) <= 0.3 + 1e-7
    small = 0.01 * u
    np.testing.assert_allclose(project_controls(small, 0.3), small - small.mean(-1, keepdims=True), atol=1e-7)


def test_action_keeps_the_state_within_limits():
    arc = jnp.array([[1.601, 2.2, 2.199]] * 4)
    u = jnp.array([[-0.3, 0.3, 0.0]] * 4)
    v = limit_to_state_bounds(arc, u, 0.05, SPEC)
    nxt = arc + 0.05 * v
    assert float(nxt.min()) >= SPEC.l_min - 1e-6
    np.testing.assert_allclose(v.sum(-1), 0.0, atol=1e-7)


def test_deterministic_and_no_recompilation(exact_mppi):
    arc0 = np.asarray(SPEC.straight_state())
    goal = np.array([1.0, 0.5, 7.0])
    exact_mppi.step(exact_mppi.init(jax.random.PRNGKey(0)), arc0, goal, None)
    compiled = mppi_step._cache_size()
    # Another controller with the same robot and settings shares the compiled program.
    m = Controller(SPEC, make_shape("spheres:2", SPEC), SMALL)
    a1, s1, i1 = m.step(m.init(jax.random.PRNGKey(3)), arc0, goal, np.ones((10, 3)) * 3)
    a2, s2, i2 = m.step(m.init(jax.random.PRNGKey(3)), arc0, goal, np.ones((10, 3)) * 3)
    np.testing.assert_array_equal(a1, a2)
    np.testing.assert_array_equal(s1.mppi.nominal, s2.mppi.nominal)
    a3, _, _ = m.step(m.init(jax.random.PRNGKey(4)), arc0, goal, np.ones((10, 3)) * 3)
    assert not np.array_equal(a1, a3)
    # New states, goals and clouds of other sizes (incl. empty) reuse the program.
    rng = np.random.default_rng(0)
    st = s1
    for n in (0, 1, 17, 64):
        arc = np.asarray(sample_arc_lengths(jax.random.PRNGKey(n), SPEC, (4,)))
        _, st, info = m.step(st, arc, rng.normal(size=3) * 3, rng.normal(size=(n, 3)) * 3)
    assert mppi_step._cache_size() == compiled
    assert info.plan.shape == (SMALL.mppi.horizon + 1, 3)
    assert info.rollout_min_distance.shape == (SMALL.mppi.samples, SMALL.mppi.horizon)
    assert 1.0 <= float(info.ess) <= SMALL.mppi.samples
    # A pose goal is the second (and last) variant.
    m.step(st, arc0, np.eye(4), None)
    m.step(st, arc0, np.asarray(_pose(arc)), None)
    assert mppi_step._cache_size() == compiled + 1


def test_empty_cloud_has_no_collision_cost(exact_mppi):
    action, _, info = exact_mppi.step(exact_mppi.init(jax.random.PRNGKey(0)), SPEC.straight_state(), [2.0, 0, 6.0], [])
    assert np.all(np.isfinite(action))
    assert float(info.cost_coll) == 0.0 and float(info.current_min_distance) == np.inf


def test_broad_phase_matches_brute_force_on_exact_geometry():
    shape = make_shape("exact", SPEC)
    rng = np.random.default_rng(0)
    pts = jnp.asarray(rng.uniform([-3, -3, 0], [3, 3, 8], size=(200, 3)), jnp.float32)
    mask = jnp.arange(200) < 180
    base = sample_arc_lengths(jax.random.PRNGKey(2), SPEC, (4,))
    u = project_controls(0.22 * jax.random.normal(jax.random.PRNGKey(5), (32, 5, 4, 3)), 0.3)
    arcs = base + 0.05 * jnp.cumsum(u, axis=1)

    @jax.jit  # one program for the three
    def all_three(a):
        bf = rollout_min_distances_brute(shape, a, pts, mask)
        bp = rollout_min_distances_broad(shape, a, pts, mask, 96, 16, 2)
        # Independent truth: the closed-form distance of every state.
        truth = jax.vmap(jax.vmap(lambda x: jnp.min(jnp.where(mask, robot_signed_distance(pts, x, SPEC), jnp.inf))))(a)
        return bf, bp, truth

    bf, bp, truth = all_three(arcs)
    np.testing.assert_allclose(bf, truth, atol=1e-5)
    agree = np.mean(np.abs(np.asarray(bp - bf)) <= 1e-5)
    assert agree >= 0.99
    assert np.all(np.asarray(bp) >= np.asarray(bf) - 1e-5)  # a subset never finds a nearer point


def _box_surface_cloud(centre, size, density, seed):
    """A box's faces observed as a scenario observes them: ``round(density * area)`` uniform points per face."""
    return make_observer(World(boxes=(Box(centre, size),), density=density), seed).observe(0.0)


_clearance = jax.jit(lambda p, a: jnp.min(robot_signed_distance(p, a, SPEC)))
_pose = jax.jit(lambda a: end_effector_pose(a, SPEC))  # eager, FK would compile op by op


def _tip(arc):
    return _pose(jnp.asarray(arc))[:3, 3]


_project = jax.jit(lambda a: project_state(a, SPEC))


def _drive(m, arc, goal, points, steps, key=0, judge=None):
    """Closed loop; returns the final goal distance and the smallest exact distance to
    ``judge`` (default: the points the controller sees) over the run."""
    st = m.init(jax.random.PRNGKey(key))
    arc = jnp.asarray(arc, jnp.float32)
    pts = None if points is None else np.asarray(points)
    judge = pts if judge is None else np.asarray(judge)
    min_exact, dist = np.inf, np.inf
    for _ in range(steps):
        action, st, _ = m.step(st, arc, goal, pts)
        arc = _project(arc + action * m.config.mppi.dt)  # remove float drift of the sum
        if judge is not None:
            min_exact = min(min_exact, float(_clearance(jnp.asarray(judge), arc)))
        dist = float(np.linalg.norm(np.asarray(_tip(jnp.asarray(arc))) - goal))
        if dist < 0.2:
            break
    return dist, min_exact


def test_reaches_a_reachable_goal_without_obstacles():
    goal_arc = sample_arc_lengths(jax.random.PRNGKey(3), SPEC, (4,))
    goal = np.asarray(_tip(goal_arc))
    m = Controller(SPEC, make_shape("spheres:2", SPEC), SMALL)
    dist, _ = _drive(m, SPEC.straight_state(), goal, None, steps=120)
    assert dist < 0.2


def test_the_first_plans_updates_start_the_robot_near_the_rate_bound_and_leave_later_steps_alone():
    """Towards a goal out of reach in free space the fastest motion runs at the rate bound; from the
    zero plan one update averages the samples' noise into half of it, and the first plan updated
    before the first move (``first_iterations``) comes near it. A step from a state whose goal
    distance is tracked is the same step whatever the setting."""
    from ncedf.presets import Observation, ours

    balls = ours(SPEC, Observation(1, ball_radius=0.1))  # the preset that races
    goal = np.array([3.0, 0.0, 3.0], np.float32)
    speeds, steps, later = {}, {}, None
    for k in (1, 5):
        cfg = dataclasses.replace(balls, mppi=dataclasses.replace(balls.mppi, samples=64, horizon=10, max_points=64,
                                                                  first_iterations=k))
        m = Controller(SPEC, make_shape("spheres:2", SPEC), cfg)
        first = [m.step(m.init(jax.random.PRNGKey(seed)), SPEC.straight_state(), goal, None) for seed in range(8)]
        speeds[k] = np.mean([np.abs(np.asarray(a)).mean() for a, _, _ in first]) / cfg.mppi.control_bound
        later = first[0][1] if later is None else later  # the state after one step, the same for both
        steps[k] = np.asarray(m.step(later, SPEC.straight_state(), goal, None)[0])
    assert speeds[5] >= 0.8 and speeds[5] - speeds[1] >= 0.25, speeds
    np.testing.assert_allclose(steps[5], steps[1], atol=1e-6)


def test_avoids_obstacles_between_robot_and_goal():
    from ncedf.model import load_model

    goal_arc = sample_arc_lengths(jax.random.PRNGKey(3), SPEC, (4,))
    goal = np.asarray(_tip(goal_arc))
    start = np.asarray(_tip(SPEC.straight_state()))
    # A ball of points (radius 0.25) halfway along the straight line from the tip to the goal.
    rng = np.random.default_rng(0)
    v = rng.normal(size=(40, 3))
    centre = 0.5 * (start + goal)
    pts = centre + 0.25 * v / np.linalg.norm(v, axis=1, keepdims=True)
    cfg = dataclasses.replace(SMALL, mppi=dataclasses.replace(SMALL.mppi, samples=128))
    m = Controller(SPEC, make_shape("ncedf", SPEC, model=load_model()), cfg)
    dist, min_exact = _drive(m, SPEC.straight_state(), goal, pts, steps=200)
    assert min_exact > 0.0
    assert dist < 0.2
    # Control: the same controller blind to the ball drives the robot through it.
    _, blind_min = _drive(m, SPEC.straight_state(), goal, None, steps=200, judge=pts)
    assert blind_min < 0.0
