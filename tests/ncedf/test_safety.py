"""The controller's stages on closed-form cases: the safety filter of the executed action, release
sampling and the unclipped update, the temperature for an effective sample size, low-pass noise,
the stall escape."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jitted import robot_clearance, step_clearance
from ncedf.controller import ControllerConfig
from ncedf.convex import fit_polytopes
from ncedf.geometry import robot_signed_distance
from ncedf.mppi import MPPIConfig, init_state, mppi_step
from ncedf.robot import RobotSpec, forward_kinematics
from ncedf.safety import SafetyFilter
from ncedf.sampling import NOMINAL_SLACK, Sampling, release_controls, sample_noise, smoothing_matrix
from ncedf.shapes import make_shape
from ncedf.temperature import MIN_ESS, TEMPERATURE_GRID, EffectiveSampleSize, Fixed, StallEscape, temperature_for_ess
from solids import sphere_surface

# One link bent at the largest rate for a long step (dt = 1 s): the tip sweeps from (0, 0, 2)
# to about (-1.24, 0, 1.33), through a thin wall of points at x = -0.6 (z in [1.7, 2.4]) that
# the end state has left behind (exact clearance about 0.32 m before and after the step).
SPEC = RobotSpec(1)
ARC = np.full((1, 3), 2.0, np.float32)
CROSSING = np.array([[0.3, -0.15, -0.15]], np.float32)
GOAL = np.array([-1.24, 0.0, 1.33], np.float32)
WALL_CONFIG = ControllerConfig(MPPIConfig(samples=16, horizon=3, covariance=1e-10, dt=1.0, max_points=512),
                               broad_phase=None)
CHECKED = dataclasses.replace(WALL_CONFIG, safety=SafetyFilter())


def _core(config, **fields):
    """``config`` with core fields changed."""
    return dataclasses.replace(config, mppi=dataclasses.replace(config.mppi, **fields))


def _wall() -> np.ndarray:
    ys, zs = np.meshgrid(np.linspace(-0.5, 0.5, 21), np.linspace(1.7, 2.4, 15))
    return np.stack([np.full(ys.size, -0.6), ys.ravel(), zs.ravel()], axis=1).astype(np.float32)


@jax.jit
def _exact_over_step(points, arc, action):
    """Exact clearance at 101 states evenly spaced over a step of dt = 1 s (the truth)."""
    s = jnp.linspace(0.0, 1.0, 101)[:, None, None]
    return jax.vmap(lambda a: jnp.min(robot_signed_distance(points, a, SPEC)))(arc + s * action)


def _run(config, points):
    shape = make_shape("exact", SPEC)
    mask = np.ones(len(points), bool)
    nominal = jnp.broadcast_to(jnp.asarray(CROSSING), (config.mppi.horizon, 1, 3))
    state = init_state(SPEC, config.mppi, jax.random.PRNGKey(0))._replace(nominal=nominal)
    return mppi_step(SPEC, config, shape, state, jnp.asarray(ARC), jnp.asarray(GOAL), jnp.asarray(points),
                     jnp.asarray(mask))


def test_the_wall_is_crossed_within_the_step_and_not_seen_at_its_ends():
    exact = np.asarray(_exact_over_step(jnp.asarray(_wall()), jnp.asarray(ARC), jnp.asarray(CROSSING)))
    assert exact[0] > 0.3 and exact[-1] > 0.3
    assert exact.min() < -0.1


def test_safety_check_refuses_an_action_that_crosses_a_thin_wall():
    wall = _wall()
    unchecked, _, info = _run(WALL_CONFIG, wall)
    # Without the check the controller executes the crossing (its rollouts only see the end state).
    np.testing.assert_allclose(unchecked, CROSSING, atol=1e-4)
    assert float(info.predicted_min_distance) > WALL_CONFIG.mppi.safety_margin
    assert float(jnp.min(_exact_over_step(jnp.asarray(wall), jnp.asarray(ARC), unchecked))) < 0

    action, _, info = _run(CHECKED, wall)
    assert int(info.action_choice) != 0
    assert float(info.action_clearance) >= CHECKED.mppi.safety_margin
    assert float(jnp.min(_exact_over_step(jnp.asarray(wall), jnp.asarray(ARC), action))) >= 0.0


def test_safety_check_keeps_a_safe_action():
    far = _wall() + np.array([-5.0, 0.0, 0.0], np.float32)  # the same wall out of reach
    unchecked, _, _ = _run(WALL_CONFIG, far)
    action, _, info = _run(CHECKED, far)
    np.testing.assert_array_equal(action, unchecked)
    assert int(info.action_choice) == 0


def test_a_refused_plan_is_not_the_next_warm_start_with_follow_executed():
    # Every sample is the crossing (covariance 1e-10), so its rollouts cannot turn the plan away:
    # without follow_executed the refused crossing stays the plan; with it the next plan is the
    # executed fallback's (the plan is constant over the horizon, so its next first control is
    # the executed action).
    wall = _wall()
    config = CHECKED
    horizon = config.mppi.horizon
    action, kept, info = _run(config, wall)
    assert int(info.action_choice) != 0
    np.testing.assert_allclose(np.asarray(kept.nominal), np.broadcast_to(CROSSING, (horizon, 1, 3)), atol=1e-4)
    followed_action, followed, followed_info = _run(
        dataclasses.replace(config, safety=SafetyFilter(follow_executed=True)), wall)
    np.testing.assert_array_equal(followed_action, action)
    assert int(followed_info.action_choice) == int(info.action_choice)
    np.testing.assert_allclose(np.asarray(followed.nominal),
                               np.broadcast_to(np.asarray(action), (horizon, 1, 3)), atol=1e-6)
    assert float(jnp.min(_exact_over_step(jnp.asarray(wall), jnp.asarray(ARC), followed.nominal[0]))) >= 0.0


def test_follow_executed_changes_nothing_when_the_plan_passes_the_check():
    far = _wall() + np.array([-5.0, 0.0, 0.0], np.float32)
    config = _core(CHECKED, covariance=0.05)
    action, state, info = _run(config, far)
    followed_action, followed, _ = _run(dataclasses.replace(config, safety=SafetyFilter(follow_executed=True)), far)
    assert int(info.action_choice) == 0
    np.testing.assert_array_equal(followed_action, action)
    np.testing.assert_array_equal(followed.nominal, state.nominal)


def test_sweep_first_scores_the_first_step_over_its_crossing():
    wall = _wall()
    _, _, plain = _run(WALL_CONFIG, wall)
    _, _, swept = _run(dataclasses.replace(WALL_CONFIG, safety=SafetyFilter(sweep_first=True)), wall)
    # Every sample is the crossing (covariance 1e-10): its end state is clear, its step is not.
    truth = min(float(jnp.min(robot_signed_distance(jnp.asarray(wall), jnp.asarray(ARC + s * CROSSING), SPEC)))
                for s in (0.25, 0.5, 0.75, 1.0))
    assert truth < -0.1
    assert np.all(np.asarray(plain.rollout_min_distance)[:, 0] > 0.3)
    np.testing.assert_allclose(np.asarray(swept.rollout_min_distance)[:, 0], truth, atol=1e-4)
    # The later steps are scored alike: two programs, so equal up to float rounding (XLA may fuse them apart).
    np.testing.assert_allclose(swept.rollout_min_distance[:, 1:], plain.rollout_min_distance[:, 1:], rtol=0, atol=1e-6)
    # The crossing is now charged the collision cost's ceiling (1 / epsilon) at x^1.
    assert float(swept.cost_coll) - float(plain.cost_coll) > 0.9 * WALL_CONFIG.mppi.w_coll / WALL_CONFIG.mppi.epsilon


@pytest.mark.parametrize("broad_phase", [False, True])
def test_step_clearance_is_the_min_over_the_substeps(broad_phase):
    shape = make_shape("exact", SPEC)
    # The wall, and a dense patch beside the straight link on the other side: the points nearest
    # to the candidates' mean state are the patch's, those nearest to the crossing are the wall's.
    ys, zs = np.meshgrid(np.linspace(-0.3, 0.3, 20), np.linspace(0.5, 1.5, 40))
    patch = np.stack([np.full(ys.size, 0.35), ys.ravel(), zs.ravel()], axis=1).astype(np.float32)
    wall = jnp.asarray(np.concatenate([_wall(), patch]))
    # Candidates that move apart (the broad phase must pick points near each one, not their mean).
    sideways = jnp.asarray([[0.0, 0.26, -0.26]])
    actions = jnp.stack([jnp.asarray(CROSSING), 0.25 * jnp.asarray(CROSSING), jnp.zeros_like(CROSSING), sideways])
    broad = ControllerConfig().broad_phase if broad_phase else None
    got = step_clearance(1.0, 4, broad, shape, jnp.asarray(ARC), actions, wall, jnp.ones(len(wall), bool))
    for action, value in zip(actions, np.asarray(got)):
        truth = min(float(jnp.min(robot_signed_distance(wall, jnp.asarray(ARC) + s * action, SPEC)))
                    for s in (0.25, 0.5, 0.75, 1.0))
        assert value == pytest.approx(truth, abs=1e-5)
    if not broad_phase:  # all actions in one call (sweep_first's form) give the same minima
        shared = step_clearance(1.0, 4, broad, shape, jnp.asarray(ARC), actions, wall, jnp.ones(len(wall), bool),
                                shared=True)
        np.testing.assert_allclose(shared, got, atol=1e-6)


def test_the_check_scores_a_ball_moving_away_as_if_it_may_turn_back():
    """A still link beside a ball that moves away at 0.2 m/s: over a 1 s step the check takes the
    ball anywhere within 0.2 m of where it is (it may turn), so the clearance is the clearance now
    less 0.2 m, not the larger clearance where the ball is heading."""
    surface = sphere_surface(np.random.default_rng(3), (0.9, 0.0, 1.5), 0.3, 30)
    ball = fit_polytopes(surface, 1.0, velocity=np.tile([0.2, 0.0, 0.0], (30, 1)))
    shape, arc = make_shape("exact", SPEC), jnp.asarray(ARC)
    frames = forward_kinematics(arc, SPEC)
    now, ahead = (float(robot_clearance(arc, frames, SPEC, ball, t)) for t in (0.0, 1.0))
    assert ahead - now == pytest.approx(0.2, abs=1e-5)
    still = jnp.zeros((1, 1, 3), jnp.float32)
    got = step_clearance(1.0, 4, None, shape, arc, still, jnp.zeros((1, 3)), jnp.zeros(1, bool), ball)
    assert float(got[0]) == pytest.approx(now - 0.2, abs=1e-5)


def test_release_controls_zero_sum_and_bounds():
    free = 0.4 * jax.random.normal(jax.random.PRNGKey(0), (1000, 3, 2))
    u = np.asarray(release_controls(free, 0.3))
    np.testing.assert_allclose(u.sum(-1), 0.0, atol=1e-6)
    assert np.abs(u[..., :2]).max() <= 0.3 and np.abs(u[..., 2]).max() <= 0.6 + 1e-6
    assert np.abs(u[..., 2]).max() > 0.3  # the derived rate goes past the bound
    inside = np.all(np.abs(np.asarray(free)) <= 0.3, axis=-1)
    np.testing.assert_array_equal(u[inside][:, :2], np.asarray(free)[inside])


def test_release_sampling_keeps_zero_sum_in_the_rollouts():
    config = dataclasses.replace(_core(WALL_CONFIG, covariance=0.1), sampling=Sampling("release", clip=0.5))
    action, state, _ = _run(config, _wall() + np.array([-5.0, 0.0, 0.0], np.float32))
    np.testing.assert_allclose(np.asarray(state.nominal).sum(-1), 0.0, atol=1e-6)
    np.testing.assert_allclose(np.asarray(action).sum(-1), 0.0, atol=1e-6)


@pytest.mark.parametrize("beta", [0.0, 0.5, 0.9])
def test_smoothing_matrix_gives_the_stationary_low_pass_covariance(beta):
    L = smoothing_matrix(8, beta).astype(np.float64)
    lag = np.abs(np.arange(8)[:, None] - np.arange(8)[None, :])
    np.testing.assert_allclose(L @ L.T, beta ** lag, atol=1e-6)  # AR(1): unit variance, correlation beta^lag


@pytest.mark.parametrize("n, target", [(800, 0.01), (800, 0.1), (800, 0.5), (16, 0.02)])
def test_temperature_for_ess_is_the_smallest_grid_value_that_reaches_the_target(n, target):
    norm = jax.random.uniform(jax.random.PRNGKey(1), (n,)).at[3].set(0.0).at[7].set(1.0)
    lam = float(temperature_for_ess(norm, target))
    wanted = max(target * n, MIN_ESS)  # 16 rollouts: the floor, not 0.32 samples

    def ess(value):
        w = np.exp(-np.asarray(norm, np.float64) / value)
        return w.sum() ** 2 / (w * w).sum()

    grid = np.asarray(TEMPERATURE_GRID, np.float32)
    i = int(np.argmin(np.abs(grid - lam)))
    assert ess(grid[i]) >= wanted * (1 - 1e-4)
    assert i == 0 or ess(grid[i - 1]) < wanted


# A 1-link robot far from its only (distant) point, with almost uniform weights (lambda = 1e6), so the
# update is the plain mean of the samples; the noise is rebuilt from the step's key split.
MEAN_CONFIG = ControllerConfig(MPPIConfig(samples=64, horizon=3, covariance=0.1, max_points=512),
                               sampling=Sampling("release", clip=0.5), temperature=Fixed(1e6), broad_phase=None)
FAR = np.array([[50.0, 50.0, 50.0]], np.float32)


def _mean_step(config, nominal, goal=(1.0, 0.0, 1.5)):
    shape = make_shape("exact", SPEC)
    c = config.mppi
    state = init_state(SPEC, c, jax.random.PRNGKey(3))._replace(nominal=jnp.asarray(nominal, jnp.float32))
    eps = np.asarray(sample_noise(config.sampling, c.covariance, c.samples, jax.random.split(state.key)[1],
                                  state.nominal.shape, jnp.float32))
    out = mppi_step(SPEC, config, shape, state, jnp.asarray(ARC), jnp.asarray(goal, jnp.float32), jnp.asarray(FAR),
                    jnp.ones(1, bool))
    return eps, out


def test_unclipped_update_keeps_a_saturated_plan_at_the_bound():
    # the plan's free rates beyond the bound (0.45 > 0.3): every sample's first free rate is near or at it
    nominal = np.broadcast_to(np.array([0.45, -0.45, 0.0], np.float32), (3, 1, 3))
    bound = MEAN_CONFIG.mppi.control_bound
    eps, (clipped_action, clipped_state, _) = _mean_step(MEAN_CONFIG, nominal)
    raw = nominal + eps.mean(axis=0)  # (H, M, 3): the truth of the unclipped update
    mean_of_bounded = np.asarray(release_controls(jnp.asarray(nominal[None] + eps)[..., :2], bound)).mean(axis=0)
    np.testing.assert_allclose(clipped_action, mean_of_bounded[0], atol=1e-5)
    assert np.abs(np.asarray(clipped_action)[0, :2]).max() < bound - 0.01  # the mean lies inside the bound

    config = dataclasses.replace(MEAN_CONFIG, sampling=Sampling("release", clip=0.5, unclipped=True))
    eps2, (action, state, _) = _mean_step(config, nominal)
    np.testing.assert_array_equal(eps2, eps)
    expected = np.asarray(release_controls(jnp.asarray(raw[0, :, :2]), bound))
    np.testing.assert_allclose(action, expected, atol=1e-5)
    assert np.all(np.abs(raw[0, 0, :2]) > bound)  # so the executed rates are at the bound
    np.testing.assert_allclose(np.abs(np.asarray(action)[0, :2]), bound, atol=1e-6)
    slack = NOMINAL_SLACK * bound
    np.testing.assert_allclose(state.nominal[:2], np.clip(raw[1:], -slack, slack), atol=1e-5)
    np.testing.assert_allclose(state.nominal[2], np.clip(raw[2], -slack, slack), atol=1e-5)  # last repeated


@pytest.mark.parametrize("goal_reach", [False, True])
def test_goal_cost_of_the_selected_rollout(goal_reach):
    # the truth: rollout states rebuilt from the noise, the goal distance per state with numpy, and for
    # goal_reach its running minimum (terminal state charged its own distance)
    config = dataclasses.replace(_core(MEAN_CONFIG, horizon=6, w_goal_terminal=22.0, goal_reach=goal_reach),
                                 temperature=Fixed(0.02))
    goal = np.array([-0.6, 0.0, 1.8], np.float32)
    nominal = np.broadcast_to(np.array([0.2, -0.2, 0.0], np.float32), (6, 1, 3))
    eps, (_, _, info) = _mean_step(config, nominal, goal)
    c = config.mppi
    u = np.asarray(release_controls(jnp.asarray(nominal[None] + eps)[..., :2], c.control_bound))
    arcs = ARC[None, None] + c.dt * np.cumsum(u, axis=1)  # (N, H, 1, 3)
    tips = np.asarray(forward_kinematics(jnp.asarray(arcs), SPEC))[..., -1, :3, 3].astype(np.float64)
    d = np.linalg.norm(tips - goal, axis=-1)  # (N, H)
    assert np.any(np.diff(d, axis=1) > 1e-3), "some rollouts must move away from the goal for this to mean anything"
    running = np.minimum.accumulate(d, axis=1) if goal_reach else d
    cost = c.w_goal * running[:, :-1].sum(axis=1) + c.w_goal_terminal * d[:, -1]
    np.testing.assert_allclose(float(info.cost_goal), cost[int(info.selected)], rtol=1e-4)


STALL_CONFIG = ControllerConfig(MPPIConfig(samples=400, horizon=5, max_points=512, progress=0.05), broad_phase=None,
                                temperature=EffectiveSampleSize(0.1, StallEscape(after=3, target=0.02)))


def _stall_step(best_goal, stalled):
    """One step of a 2-link robot towards a goal 1.2 m from its tip, beside a few points, from a state
    whose best goal distance and stall count are given; returns (tip distance to the goal, info, state)."""
    spec = RobotSpec(2)
    shape = make_shape("exact", spec)
    goal = jnp.array([1.0, 0.5, 3.5], jnp.float32)
    points = jnp.array([[0.8, 0.0, 2.0], [0.8, 0.3, 2.5], [-0.8, 0.0, 3.0]], jnp.float32)
    state = init_state(spec, STALL_CONFIG.mppi, jax.random.PRNGKey(2))._replace(
        best_goal=jnp.float32(best_goal), stalled=jnp.int32(stalled))
    arc = jnp.full((2, 3), spec.length, jnp.float32)
    _, new, info = mppi_step(spec, STALL_CONFIG, shape, state, arc, goal, points, jnp.ones(3, bool))
    tip = np.array([0.0, 0.0, 2 * spec.length])  # the straight robot's tip
    return float(np.linalg.norm(tip - np.asarray(goal))), info, new


def test_stall_count_restarts_on_progress_and_grows_without_it():
    d, _, new = _stall_step(np.inf, 0)  # the first step: progress from +inf
    assert (float(new.best_goal), int(new.stalled)) == (pytest.approx(d, abs=1e-5), 0)
    _, _, new = _stall_step(d + 0.051, 7)  # fell by more than the progress threshold: progress
    assert (float(new.best_goal), int(new.stalled)) == (pytest.approx(d, abs=1e-5), 0)
    _, _, new = _stall_step(d + 0.049, 7)  # fell by less: no progress, the best is kept
    assert (float(new.best_goal), int(new.stalled)) == (pytest.approx(d + 0.049, abs=1e-5), 8)


def test_a_stalled_robot_gets_the_sharper_temperature():
    d = _stall_step(np.inf, 0)[0]
    # The same samples and costs (same key and cloud); only the stall count differs.
    infos = {stalled: _stall_step(d, stalled)[1] for stalled in (1, 2, 3, 9)}
    n, ess = STALL_CONFIG.mppi.samples, STALL_CONFIG.temperature
    for stalled, info in infos.items():  # the count after the step is stalled + 1
        target = ess.escape.target if stalled + 1 > ess.escape.after else ess.target
        assert float(info.ess) >= target * n * (1 - 1e-4)
    assert float(infos[1].temperature) == float(infos[2].temperature)  # counts 2, 3: not beyond the escape's
    assert float(infos[3].temperature) < float(infos[2].temperature)  # count 4: stalled
    assert float(infos[3].ess) < ess.target * n  # sharper than the unstalled target allows
    assert float(infos[9].temperature) == float(infos[3].temperature)
