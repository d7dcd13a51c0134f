"""ncedf.route and the controller's recovery stage (ncedf.recovery): the planned path judged by the exact
robot-box distance, and its execution under the safety check."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.spatial import cKDTree

import ncedf.controller as controller_module
import ncedf.route as route_module
from ncedf.controller import Controller, ControllerConfig
from ncedf.convex import fit_polytopes
from ncedf.mppi import MPPIConfig
from ncedf.obstacle_model import ConvexModel, soft_clearance
from ncedf.recovery import RouteRecovery, RouteState
from ncedf.robot import (RobotSpec, config_to_arc_lengths, end_effector_pose, forward_kinematics, sample_arc_lengths,
                         validate_state)
from ncedf.safety import SafetyFilter
from ncedf.route import (GoalLift, RouteConfig, around, between, bridge, clearances, ends, goal_states,
                         lazy_shortest_path, plan_route, roadmap_edges, shortest_path, tips)
from ncedf.shapes import make_shape
from scenarios.observe import make_observer
from scenarios.truth import true_distances_batch
from scenarios.world import Box, World
from solids import ported_wall

# A two-link robot standing straight up (tip at (0, 0, 4)) and a goal below a bar that blocks the
# straight way in arc lengths to the goal's states.
SPEC = RobotSpec(2)
START = np.full((2, 3), 2.0, np.float32)
BAR = Box((1.3, 0.0, 3.0), (0.6, 3.0, 0.6))
GOAL = np.array([2.2, 0.0, 2.2])
ROUTE = RouteConfig(samples=600, local_samples=200, goal_candidates=100, lift=GoalLift(candidates=100, iterations=50))


@pytest.fixture(scope="module")
def cloud():
    return np.asarray(make_observer(World(boxes=(BAR,), density=30.0), 0).observe(0.0), np.float32)


@pytest.fixture(scope="module")
def polytopes(cloud):
    return fit_polytopes(cloud, 1.0)


def _exact(states: np.ndarray) -> np.ndarray:
    return true_distances_batch(World(boxes=(BAR,)), SPEC, states, np.zeros(len(states)))[:, 0]


def test_the_route_goes_round_the_bar_to_the_goal(polytopes):
    route = plan_route(SPEC, polytopes, START, GOAL, jax.random.PRNGKey(0), ROUTE)
    assert route is not None
    np.testing.assert_array_equal(route[0], START)
    assert np.max(np.abs(np.diff(route, axis=0))) <= ROUTE.path_step + 1e-6
    assert np.linalg.norm(tips(route[-1:], SPEC)[0] - GOAL) <= ROUTE.goal_tolerance
    assert _exact(route).min() > 0.0  # clear of the bar all the way, by the exact distance
    straight, _ = between(START[None], route[-1:], ROUTE.path_step)
    assert _exact(straight).min() < 0.0  # the straight way to the same end state crosses the bar


def test_a_robot_stalled_nearer_than_the_edge_clearance_leaves_first_never_nearer(polytopes):
    """A start pressed against the bar (model clearance 0.03-0.12 m, below ``edge_clearance``): no edge from it
    to the states around it keeps ``edge_clearance``, so the roadmap alone holds no route; the route first
    leaves along a segment never nearer the bar than the start, then keeps the edges' clearance."""
    states = np.asarray(sample_arc_lengths(jax.random.PRNGKey(3), SPEC, (4000, 2)), np.float32)
    near = clearances(states, SPEC, polytopes)
    start = states[np.flatnonzero((near > 0.03) & (near < 0.12))[0]]
    now = clearances(start[None], SPEC, polytopes)[0]
    key = jax.random.PRNGKey(0)
    local = np.asarray(around(jnp.asarray(start), jax.random.fold_in(key, 1), SPEC, ROUTE.local_samples,
                              ROUTE.local_radius), np.float32)
    local = local[clearances(local, SPEC, polytopes) >= ROUTE.edge_clearance]
    assert not route_module.clear_edges(np.repeat(start[None], len(local), axis=0), local, SPEC, polytopes,
                                        ROUTE).any()
    route = plan_route(SPEC, polytopes, start, GOAL, key, ROUTE)
    assert route is not None
    np.testing.assert_array_equal(route[0], start)
    assert np.max(np.abs(np.diff(route, axis=0))) <= ROUTE.path_step + 1e-6
    assert np.linalg.norm(tips(route[-1:], SPEC)[0] - GOAL) <= ROUTE.goal_tolerance
    along = clearances(route, SPEC, polytopes)
    assert along.min() >= now - 1e-6 and _exact(route).min() > 0.0
    left = np.argmax(along >= ROUTE.edge_clearance)  # once out, the roadmap's edges keep their clearance
    assert left > 0 and along[left:].min() >= ROUTE.edge_clearance - 1e-6


@pytest.mark.parametrize("check_step, every_state_checked", [(RouteConfig().check_step, True), (0.01, False)])
def test_every_state_of_the_route_was_checked_clear_at_the_default_check_step(polytopes, monkeypatch, check_step,
                                                                              every_state_checked):
    """The controller executes the route's states: each after the start is one the planner scored at
    ``edge_clearance`` or more (the states between coarser checks were never scored)."""
    scored = []

    def recording(arcs, spec, model):
        clear = clearances(arcs, spec, model)
        scored.append((np.asarray(arcs).reshape(len(arcs), -1), clear))
        return clear

    monkeypatch.setattr(route_module, "clearances", recording)
    config = dataclasses.replace(ROUTE, check_step=check_step)
    route = plan_route(SPEC, polytopes, START, GOAL, jax.random.PRNGKey(0), config)
    assert route is not None
    checked = np.concatenate([arcs[clear >= config.edge_clearance] for arcs, clear in scored])
    nearest, _ = cKDTree(checked).query(route[1:].reshape(len(route) - 1, -1))
    assert np.all(nearest < 1e-5) == every_state_checked


def test_no_route_to_a_goal_inside_the_bar(polytopes):
    assert plan_route(SPEC, polytopes, START, np.asarray(BAR.centre), jax.random.PRNGKey(0), ROUTE) is None


@pytest.mark.parametrize("links", [2, 4])
def test_refine_puts_the_tip_on_a_reachable_goal(links):
    # the goal: the tip of a random valid state. From that state moved by up to 0.05 m per arc length,
    # damped least squares must converge onto the goal (to float precision); from other random states whose
    # tips lie within 1.5 m of it, most must come within the goal tolerance (what the roadmap needs). Every
    # state stays valid.
    spec = RobotSpec(links)
    config = RouteConfig()
    drawn = np.asarray(sample_arc_lengths(jax.random.PRNGKey(links), spec, (4000, links)), np.float32)
    ends = tips(drawn, spec)
    goal = ends[0]
    shaken = np.asarray(around(jnp.asarray(drawn[0]), jax.random.PRNGKey(9), spec, 32, 0.05), np.float32)
    far = drawn[1:][np.linalg.norm(ends[1:] - goal, axis=1) < 1.5][:32]
    assert len(far) >= 16

    def refined(starts, iterations=config.goal_iterations):
        moved = np.asarray(route_module._refine(jnp.asarray(starts), jnp.asarray(goal, jnp.float32), spec,
                                                iterations, config.goal_damping, config.goal_move))
        for arc in moved:
            validate_state(arc, spec)
        return moved, np.linalg.norm(tips(moved, spec) - goal, axis=1)

    near = refined(shaken)[1]
    assert np.median(near) < 1e-5 and near.max() < 0.01  # 2 links: one of 32 held 5 mm off by a chamber limit
    assert np.mean(refined(far)[1] <= config.goal_tolerance) >= 0.9
    # one iteration moves no arc length by more than goal_move before the projection, which is non-expansive
    once, _ = refined(far, 1)
    assert np.max(np.linalg.norm(once - far, axis=-1)) <= np.sqrt(3) * config.goal_move + 1e-5


#: A goal beside the bar at its height: most bodies refined onto it cross the bar. The lift's test settings.
BESIDE = np.array([2.0, 0.0, 3.0])
LIFT = dataclasses.replace(ROUTE, node_clearance=0.1, edge_clearance=0.05, lift=GoalLift(candidates=100, iterations=100))


def _free(polytopes, config, key=5):
    drawn = np.asarray(sample_arc_lengths(jax.random.PRNGKey(key), SPEC, (config.samples, SPEC.n_links)), np.float32)
    return drawn[clearances(drawn, SPEC, polytopes) >= config.node_clearance]


def test_the_lift_climbs_bodies_out_of_the_bar_with_the_tip_kept_on_the_goal(polytopes):
    """Bodies refined onto the goal that cross the bar (by the exact distance) climb out of it in the tip's
    null space: many end clear, where as many refinement steps without the climb free few; the tips stay on
    the goal, and none that was clear ends in the bar."""
    free = _free(polytopes, LIFT)
    near = np.argsort(np.linalg.norm(tips(free, SPEC) - BESIDE, axis=1))[:LIFT.lift.candidates]
    refined = route_module._refined(free[near], BESIDE, SPEC, LIFT, size=LIFT.lift.candidates)
    lifted = route_module._refined(refined, BESIDE, SPEC, LIFT, size=LIFT.lift.candidates, fitted=polytopes)
    unlifted = np.asarray(route_module._refine(jnp.asarray(refined), jnp.asarray(BESIDE, jnp.float32), SPEC,
                                               LIFT.lift.iterations, LIFT.goal_damping, LIFT.goal_move))
    before, after = _exact(refined), _exact(lifted)
    inside = before < 0.0
    assert inside.sum() >= 30
    assert np.mean(after[inside] > 0.0) >= 0.2 + np.mean(_exact(unlifted)[inside] > 0.0)
    assert np.all(after[~inside] > 0.0)
    assert np.median(after) > np.median(before) + 0.2
    assert np.max(np.linalg.norm(tips(lifted, SPEC) - BESIDE, axis=1)) <= 0.05
    for arc in lifted:
        validate_state(arc, spec=SPEC)


def test_the_soft_clearance_has_a_finite_gradient_with_a_ball_inside_the_bar(polytopes):
    """A body through the bar (cover balls' centres inside its box): the gradient that lifts it is finite and
    not zero (a square root's derivative at 0 would make it NaN)."""
    drawn = np.asarray(sample_arc_lengths(jax.random.PRNGKey(3), SPEC, (400, SPEC.n_links)), np.float32)
    depth = _exact(drawn)
    arc = jnp.asarray(drawn[np.argmin(depth)])
    grad = jax.jit(jax.grad(lambda a: soft_clearance(polytopes, a, forward_kinematics(a, SPEC), SPEC)))(arc)
    assert depth.min() < -SPEC.radius  # the backbone itself inside the bar, so cover balls' centres are
    assert np.all(np.isfinite(grad)) and np.any(np.asarray(grad) != 0.0)


def test_lifted_goal_states_are_more_and_clear_of_the_bar(polytopes):
    free = _free(polytopes, LIFT)
    plain, lifted = (goal_states(free, BESIDE, SPEC, polytopes, LIFT, lifted=up) for up in (False, True))
    assert len(lifted) > len(plain)
    assert np.all(_exact(lifted) > 0.0)
    assert np.max(np.linalg.norm(tips(lifted, SPEC) - BESIDE, axis=1)) <= LIFT.goal_tolerance


def test_where_the_first_try_holds_no_goal_state_the_lifted_ones_give_the_route(polytopes, monkeypatch):
    """The second try of plan_route: with the first try's goal states taken away, the route ends on a lifted
    goal state, clear of the bar all the way by the exact distance."""
    kept = goal_states
    monkeypatch.setattr(route_module, "goal_states",
                        lambda free, *rest, lifted=False: kept(free, *rest, lifted=lifted) if lifted else free[:0])
    route = plan_route(SPEC, polytopes, START, BESIDE, jax.random.PRNGKey(0), LIFT)
    assert route is not None
    np.testing.assert_array_equal(route[0], START)
    assert np.linalg.norm(tips(route[-1:], SPEC)[0] - BESIDE) <= LIFT.goal_tolerance
    assert _exact(route).min() > 0.0


def test_the_second_try_checks_no_edge_the_first_checked(polytopes, monkeypatch):
    """plan_route's two searches share their edge checks: with the first search's route taken away (so a
    second try runs), no pair of states is checked twice by the searches (the shortcut after them checks its
    own), and the second roadmap begins with the first's nodes."""
    calls, pairs = [], []
    search, check = route_module.roadmap_path, route_module.edge_clearances

    def first_fails(others, targets, *rest):
        calls.append(np.concatenate([others, targets]))
        path = search(others, targets, *rest)
        calls.append(None)  # the search is over
        return None if len(calls) == 2 else path

    def recorded(a, b, *rest):
        if calls and calls[-1] is not None:
            pairs.extend(x.tobytes() + y.tobytes() for x, y in zip(a, b))
        return check(a, b, *rest)

    monkeypatch.setattr(route_module, "roadmap_path", first_fails)
    monkeypatch.setattr(route_module, "edge_clearances", recorded)
    route = plan_route(SPEC, polytopes, START, GOAL, jax.random.PRNGKey(0), ROUTE)
    first, second = calls[::2]
    assert len(calls) == 4 and route is not None
    assert len(second) > len(first) and np.array_equal(second[:len(first)], first)
    assert len(pairs) > 0 and len(set(pairs)) == len(pairs)


def test_no_second_try_where_the_first_plans_a_route_or_for_a_pose(polytopes, monkeypatch):
    lifted = []
    kept = goal_states
    monkeypatch.setattr(route_module, "goal_states",
                        lambda *args, **kw: lifted.append(kw.get("lifted", False)) or kept(*args, **kw))
    assert plan_route(SPEC, polytopes, START, GOAL, jax.random.PRNGKey(0), ROUTE) is not None
    assert plan_route(SPEC, polytopes, START, np.asarray(BAR.centre), jax.random.PRNGKey(0), ROUTE,
                      np.array([1.0, 0.0, 0.0]), aligned_only=True) is None
    assert lifted and not any(lifted)


def test_a_bridge_is_a_chain_of_short_clear_branches_from_a_free_state_to_a_goal_state(polytopes):
    """The bridge's tree, linked only to free states whose tips are over 1.5 m from the goal (none of the goal
    states' neighbours): the chain from its free state to a goal state moves no arc length by more than the
    bridge's step between states, every state checked along it is clear of the bar by the exact distance,
    and it ends on a goal state; with no goal state, no chain."""
    free = _free(polytopes, ROUTE)
    goals = goal_states(free, GOAL, SPEC, polytopes, ROUTE)
    far = free[np.linalg.norm(tips(free, SPEC) - GOAL, axis=1) > 1.5]
    end, chain = bridge(goals, far, SPEC, polytopes, ROUTE, jax.random.PRNGKey(2))
    assert len(goals) and end >= 0 and len(chain) >= 2
    assert any(np.array_equal(chain[-1], g) for g in goals)
    assert np.max(np.abs(np.diff(chain, axis=0))) <= ROUTE.bridge.step + 1e-6
    whole = np.concatenate([far[end][None], chain])
    inner, _ = between(whole[:-1], whole[1:], ROUTE.check_step)
    assert _exact(np.concatenate([whole, inner])).min() > 0.0
    assert bridge(goals[:0], far, SPEC, polytopes, ROUTE, jax.random.PRNGKey(2))[0] == -1


def test_where_neither_search_finds_a_route_the_bridge_gives_one(polytopes, monkeypatch):
    """plan_route's third try: with the two searches' routes taken away, the route runs over the roadmap to
    the state the bridge links, then along the bridge to a goal state, clear of the bar all the way by the
    exact distance; a goal inside the bar (no goal state) has none."""
    bridged, kept = [], bridge
    monkeypatch.setattr(route_module, "roadmap_path", lambda *args: None)
    monkeypatch.setattr(route_module, "bridge", lambda *args: bridged.append(kept(*args)) or bridged[-1])
    route = plan_route(SPEC, polytopes, START, GOAL, jax.random.PRNGKey(0), ROUTE)
    assert route is not None and len(bridged) == 1
    np.testing.assert_array_equal(route[0], START)
    np.testing.assert_array_equal(route[-1], bridged[0][1][-1])
    assert np.max(np.abs(np.diff(route, axis=0))) <= ROUTE.path_step + 1e-6
    assert np.linalg.norm(tips(route[-1:], SPEC)[0] - GOAL) <= ROUTE.goal_tolerance
    assert _exact(route).min() > 0.0
    assert plan_route(SPEC, polytopes, START, np.asarray(BAR.centre), jax.random.PRNGKey(0), ROUTE) is None
    assert len(bridged) == 1  # no goal state inside the bar: no tree to grow, no third try


#: Link 1 bent by 1 rad towards +x, link 2 straight: its tip beyond the bar, clear of it.
BENT = np.stack([np.asarray(config_to_arc_lengths(1.0, 0.0, SPEC.link(0))), np.full(3, 2.0)])


def _bent_pose() -> np.ndarray:
    """(4, 4) the end-effector pose of BENT, a pose goal."""
    return np.asarray(end_effector_pose(jnp.asarray(BENT), SPEC), np.float64)


def _assert_ends_on(route: np.ndarray, pose: np.ndarray) -> None:
    """The route's last state has its tip on the pose's position and its axis along the pose's (within the
    route's tolerances), and every state is clear of the bar by the exact distance."""
    axis, tip = ends(route[-1:], SPEC)
    assert np.linalg.norm(tip[0] - pose[:3, 3]) <= ROUTE.goal_tolerance
    assert ROUTE.approach_weight * np.linalg.norm(axis[0] - pose[:3, 2]) <= ROUTE.goal_tolerance
    assert _exact(route).min() > 0.0


def test_a_pose_goals_third_try_grows_from_its_aligned_goal_states(polytopes, monkeypatch):
    """A pose goal (link 1 bent by 1 rad towards +x, link 2 straight: its tip beyond the bar) with the first
    search's route taken away: the bridge's route ends with the tip on the pose's position and its axis along
    the pose's, clear of the bar all the way by the exact distance."""
    monkeypatch.setattr(route_module, "roadmap_path", lambda *args: None)
    pose = _bent_pose()
    route = plan_route(SPEC, polytopes, START, pose[:3, 3], jax.random.PRNGKey(0), ROUTE, pose[:3, 2],
                       aligned_only=True)
    assert route is not None
    np.testing.assert_array_equal(route[0], START)
    _assert_ends_on(route, pose)
    assert np.max(np.abs(np.diff(route, axis=0))) <= ROUTE.path_step + 1e-6


def _roadmap(polytopes):
    """A roadmap as plan_route's: the start, free random states and goal states; each node's 8 nearest."""
    drawn = np.asarray(sample_arc_lengths(jax.random.PRNGKey(5), SPEC, (400, SPEC.n_links)), np.float32)
    free = drawn[clearances(drawn, SPEC, polytopes) >= ROUTE.node_clearance]
    targets = goal_states(free, GOAL, SPEC, polytopes, ROUTE)
    nodes = np.concatenate([START[None], free, targets])
    return (nodes, *roadmap_edges(nodes, 8), len(targets))


def test_roadmap_edges_are_each_nodes_nearest_once():
    nodes = np.random.default_rng(0).uniform(size=(60, 2, 3)).astype(np.float32)
    i, j, w = roadmap_edges(nodes, 4)
    flat = nodes.reshape(len(nodes), -1)
    distance = np.linalg.norm(flat[:, None] - flat[None], axis=-1)
    np.fill_diagonal(distance, np.inf)
    nearest = np.argsort(distance, axis=1)[:, :4]  # brute force
    expected = {(min(a, b), max(a, b)) for a in range(len(nodes)) for b in nearest[a]}
    assert np.all(i < j) and len(set(zip(i.tolist(), j.tolist()))) == len(i)
    assert set(zip(i.tolist(), j.tolist())) == expected  # listed by either node, kept once
    np.testing.assert_allclose(w, distance[i, j], rtol=1e-5)


@pytest.mark.parametrize("rounds", [ROUTE.lazy_rounds, 1])
def test_lazy_checks_find_the_path_that_checking_every_edge_finds(polytopes, monkeypatch, rounds):
    nodes, i, j, w, goals = _roadmap(polytopes)
    ok = route_module.edge_clearances(nodes[i], nodes[j], SPEC, polytopes, ROUTE.check_step) >= ROUTE.edge_clearance
    assert 0 < ok.sum() < len(ok)
    checked = []
    counted = route_module.edge_clearances
    monkeypatch.setattr(route_module, "edge_clearances", lambda a, *rest: checked.append(len(a)) or counted(a, *rest))
    config = dataclasses.replace(ROUTE, lazy_rounds=rounds)
    expected = shortest_path(len(nodes), i[ok], j[ok], w[ok], np.arange(len(nodes) - goals, len(nodes)))
    assert expected is not None and len(expected) > 2
    assert lazy_shortest_path(nodes, i, j, w, goals, SPEC, polytopes, config) == expected
    # A goal state whose straight edge from the start meets the bar, and no other edge: no path.
    targets = nodes[len(nodes) - goals:]
    straight = counted(np.repeat(START[None], goals, axis=0), targets, SPEC, polytopes, ROUTE.check_step)
    blocked = targets[straight < ROUTE.edge_clearance]
    assert len(blocked) > 0
    pair = np.stack([START, blocked[0]])
    assert lazy_shortest_path(pair, np.array([0]), np.array([1]), np.array([1.0]), 1, SPEC, polytopes, config) is None
    if rounds == 1:  # every edge checked at once after the first path
        assert checked[0] == len(i)
    else:
        assert sum(checked[:1]) < len(i) // 10  # the first search checks only its path's edges


def test_a_search_over_more_nodes_checks_no_edge_known_from_the_first(polytopes, monkeypatch):
    nodes, i, j, w, goals = _roadmap(polytopes)
    assert goals >= 2
    first = nodes[:-1]  # the second search's nodes begin with the first's
    fi, fj, fw = roadmap_edges(first, 8)
    checked = {}
    lazy_shortest_path(first, fi, fj, fw, goals - 1, SPEC, polytopes, dataclasses.replace(ROUTE, lazy_rounds=1), checked)
    known = dict(checked)
    pairs = [(a, b) for a, b in zip(fi.tolist(), fj.tolist()) if (a, b) in known]
    truth = route_module.edge_clearances(first[[a for a, _ in pairs]], first[[b for _, b in pairs]], SPEC, polytopes,
                                         ROUTE.check_step) >= ROUTE.edge_clearance
    assert len(pairs) == len(known) > 0 and [known[pair] for pair in pairs] == np.where(truth, 1, -1).tolist()
    every = dataclasses.replace(ROUTE, lazy_rounds=1)  # where the first path is blocked, every edge not known
    fresh = lazy_shortest_path(nodes, i, j, w, goals, SPEC, polytopes, every)
    sizes = []
    counted = route_module.edge_clearances
    monkeypatch.setattr(route_module, "edge_clearances", lambda a, *rest: sizes.append(len(a)) or counted(a, *rest))
    assert lazy_shortest_path(nodes, i, j, w, goals, SPEC, polytopes, every, checked) == fresh
    assert sum(sizes) <= len(set(zip(i.tolist(), j.tolist())) - set(known))
    assert all(checked[pair] == value for pair, value in known.items())


@pytest.mark.parametrize("batch", [1, 37, 10**9])
def test_edges_checked_in_batches_get_each_edges_least_clearance_over_all_its_states(polytopes, monkeypatch, batch):
    nodes, i, j, _, _ = _roadmap(polytopes)
    a, b = nodes[i[:60]], nodes[j[:60]]
    states, segment = between(a, b, ROUTE.check_step)
    scored = clearances(states, SPEC, polytopes)
    expected = np.array([scored[segment == e].min() if np.any(segment == e) else np.inf for e in range(len(a))])
    assert np.isfinite(expected).sum() > 50 and len(np.unique(segment)) > 50
    monkeypatch.setattr(route_module, "EDGE_BATCH", batch)  # one segment a batch, a few, all at once
    held = []
    monkeypatch.setattr(route_module, "between", lambda *args: held.append(len(between(*args)[0])) or between(*args))
    np.testing.assert_array_equal(route_module.edge_clearances(a, b, SPEC, polytopes, ROUTE.check_step), expected)
    longest = np.bincount(segment).max()
    assert max(held) <= max(batch, longest) and sum(held) == len(states)  # each state once, a batch at a time


def test_states_around_a_state_are_valid_and_within_the_radius_at_every_scale():
    spec, radius = RobotSpec(4), 0.1
    start = np.asarray([[2.0, 2.0, 2.0], [1.8, 2.1, 2.1], [2.0, 1.9, 2.1], [2.2, 1.9, 1.9]], np.float32)
    states = np.asarray(around(start, jax.random.PRNGKey(3), spec, 2000, radius))
    np.testing.assert_array_equal(states, np.asarray(around(start, jax.random.PRNGKey(3), spec, 2000, radius)))
    for state in states[::97]:
        validate_state(state, spec)  # the projection keeps every state valid
    np.testing.assert_allclose(states.sum(axis=-1), 3 * spec.length, atol=1e-5)
    # The projection onto a convex set that holds the start moves no state farther from it (per link).
    assert np.max(np.linalg.norm(states - start, axis=-1)) <= radius * np.sqrt(3) + 1e-6
    farthest = np.max(np.abs(states - start), axis=(1, 2))
    assert np.mean(farthest < 0.1 * radius) > 0.05 and np.mean(farthest > 0.8 * radius) > 0.05  # near and far


def test_between_spaces_states_evenly_inside_each_segment():
    a = np.zeros((3, 1, 3), np.float32)
    b = np.array([[[0.05, 0.0, -0.05]], [[0.001, 0.0, -0.001]], [[0.0, 0.1, -0.1]]], np.float32)
    states, segment = between(a, b, 0.01)
    np.testing.assert_array_equal(segment, [0] * 4 + [2] * 9)  # 5 and 10 steps; 1 step has nothing inside
    np.testing.assert_allclose(states[:4, 0, 0], [0.01, 0.02, 0.03, 0.04], atol=1e-7)
    np.testing.assert_allclose(states[4:, 0, 1], np.arange(1, 10) * 0.01, atol=1e-7)


def _controller() -> Controller:
    config = ControllerConfig(MPPIConfig(samples=16, horizon=3, max_points=1024), model=ConvexModel(1.0), safety=SafetyFilter(),
                              recovery=RouteRecovery(after=5, route=ROUTE))
    return Controller(SPEC, make_shape("spheres", SPEC), config)


def _with_route(state, route: np.ndarray):
    return state._replace(route=RouteState(route, 0, 0))


def _stalled(state, count: int):
    """The state after ``count`` steps without progress."""
    return state._replace(mppi=state.mppi._replace(stalled=jnp.asarray(count, jnp.int32),
                                                   best_goal=jnp.asarray(0.0, jnp.float32)))


def test_a_route_is_executed_a_step_at_a_time_and_held_where_the_check_refuses(cloud):
    mppi = _controller()
    c = mppi.config.mppi
    step = c.control_bound * c.dt
    bend = np.array([[0.3, -0.15, -0.15], [0.0, 0.0, 0.0]], np.float32) * 0.9 * step / 0.3  # within one step
    route = (START + np.arange(4)[:, None, None] * bend / 2).astype(np.float32)  # states 0.45 steps apart
    state = _with_route(mppi.init(jax.random.PRNGKey(0)), route)
    # Free space: the farthest state within one step (the second after the start), exactly.
    action, after, _ = mppi.step(state, START, GOAL)
    np.testing.assert_allclose(np.asarray(action), (route[2] - START) / c.dt, atol=1e-5)
    assert after.route.at == 2 and len(after.route.states) == 4
    # From there, the last state: the route's end, and MPPI takes over with a fresh stall count.
    action, after, _ = mppi.step(after, route[2], GOAL)
    np.testing.assert_allclose(np.asarray(action), (route[3] - route[2]) / c.dt, atol=1e-5)
    assert after.route.at == 3 and int(after.mppi.stalled) == 0
    # A small ball of points just past where the move would take the tip (its surface 0.2 m on, the link's
    # radius): refused; from where the robot stands it is 0.4 m off, so the robot holds.
    now, ahead = tips(START[None], SPEC)[0], tips(route[2:3], SPEC)[0]
    centre = ahead + 0.25 * (ahead - now) / np.linalg.norm(ahead - now)
    d = np.random.default_rng(0).normal(size=(40, 3))
    ball = (centre + 0.05 * d / np.linalg.norm(d, axis=1, keepdims=True)).astype(np.float32)
    action, after, _ = mppi.step(state, START, GOAL, ball)
    np.testing.assert_array_equal(np.asarray(action), 0.0)
    assert after.route.at == 0 and len(after.route.states) == 4


def test_a_route_refused_for_after_steps_in_a_row_is_given_up():
    """The ball of the test above in the way of the route's next move: the robot holds while the check
    refuses it, and after ``after`` refusals in a row the route is dropped and MPPI steers again."""
    mppi = _controller()
    c = mppi.config.mppi
    bend = np.array([[0.3, -0.15, -0.15], [0.0, 0.0, 0.0]], np.float32) * 0.9 * c.control_bound * c.dt / 0.3
    route = (START + np.arange(4)[:, None, None] * bend / 2).astype(np.float32)
    now, ahead = tips(START[None], SPEC)[0], tips(route[2:3], SPEC)[0]
    d = np.random.default_rng(0).normal(size=(40, 3))
    ball = (ahead + 0.25 * (ahead - now) / np.linalg.norm(ahead - now) + 0.05 * d / np.linalg.norm(d, axis=1,
                                                                                                   keepdims=True))
    state = mppi.init(jax.random.PRNGKey(0))._replace(route=RouteState(route, 0, 1))
    for k in range(1, mppi.config.recovery.after):
        action, state, _ = mppi.step(state, START, GOAL, ball.astype(np.float32))
        np.testing.assert_array_equal(np.asarray(action), 0.0)
        assert state.route.blocked == k and len(state.route.states) == 4
    _, state, _ = mppi.step(state, START, GOAL, ball.astype(np.float32))
    assert len(state.route.states) == 0 and state.route.routes == 1 and state.route.blocked == 0


def test_a_stalled_controller_plans_a_route_from_where_it_is(cloud):
    mppi = _controller()
    state = _stalled(mppi.init(jax.random.PRNGKey(0)), 50)
    _, after, _ = mppi.step(state, START, GOAL, cloud)
    route = after.route.states
    assert after.route.routes == 1 and len(route) >= 2 and int(after.mppi.stalled) == 0
    np.testing.assert_allclose(route[0], START, atol=1e-6)
    assert np.linalg.norm(tips(route[-1:], SPEC)[0] - GOAL) <= ROUTE.goal_tolerance
    assert _exact(route).min() > 0.0


def test_without_a_route_the_stall_count_goes_on_and_the_next_plan_waits(cloud):
    mppi = _controller()
    inside = np.asarray(BAR.centre)  # no goal state: no route
    state = _stalled(mppi.init(jax.random.PRNGKey(0)), 50)
    _, after, _ = mppi.step(state, START, inside, cloud)  # 51 steps without progress: a plan is due
    assert after.route.routes == 1 and len(after.route.states) == 0
    assert int(after.mppi.stalled) == 51 and float(after.mppi.best_goal) == 0.0  # the stall escape's, untouched
    _, after, _ = mppi.step(after, START, inside, cloud)
    assert after.route.routes == 1 and int(after.mppi.stalled) == 52  # the next plan at 51 + after
    _, after, _ = mppi.step(_stalled(after, 55), START, inside, cloud)
    assert after.route.routes == 2 and int(after.mppi.stalled) == 56


def test_no_route_where_the_model_left_an_obstacle_out(cloud):
    """A ported wall beside the bar is not convex, so the model leaves it out and a roadmap round the
    model would not see it: no plan, and the stall count goes on."""
    mppi = _controller()
    wall = ported_wall(spacing=(0.125, 0.5, 0.5), offset=(-6.0, 0.0, 0.0))  # behind the robot, out of its way
    both = np.concatenate([cloud, wall])
    _, state, _ = mppi.step(mppi.init(jax.random.PRNGKey(0)), START, GOAL, both)  # the wall seen still once
    _, after, _ = mppi.step(_stalled(state, 50), START, GOAL, both)
    assert after.route.routes == 0 and int(after.mppi.stalled) == 51
    _, after, _ = mppi.step(_stalled(mppi.init(jax.random.PRNGKey(0)), 50), START, GOAL, cloud)
    assert after.route.routes == 1  # the control: the bar alone gets its route


def test_a_pose_goals_route_arrives_along_its_approach_axis(cloud):
    """The pose of link 1 bent by 1 rad towards +x and link 2 straight (its tip beyond the bar, clear
    of it): the route ends with the tip at the pose's position and its axis along the pose's."""
    mppi = _controller()
    assert _exact(BENT[None])[0] > 0.1
    pose = _bent_pose()
    _, after, _ = mppi.step(_stalled(mppi.init(jax.random.PRNGKey(0)), 50), START, pose, cloud)
    route = after.route.states
    assert after.route.routes == 1 and len(route) >= 2
    _assert_ends_on(route, pose)


def test_route_settings_are_validated():
    with pytest.raises(ValueError, match="RouteRecovery.after"):
        RouteRecovery(after=-1)
    with pytest.raises(ValueError, match="RouteRecovery.route"):
        RouteRecovery(route=5)
    with pytest.raises(ValueError, match="RouteRecovery.growth"):
        RouteRecovery(growth=0.0)
    with pytest.raises(ValueError, match="RouteConfig.samples"):
        RouteConfig(samples=0)
    with pytest.raises(ValueError, match="RouteConfig.lazy_rounds"):
        RouteConfig(lazy_rounds=0)
    with pytest.raises(ValueError, match="RouteConfig.local_radius"):
        RouteConfig(local_radius=0.0)
    with pytest.raises(ValueError, match="RouteConfig.check_step"):
        dataclasses.replace(ROUTE, check_step=-0.1)
    with pytest.raises(ValueError, match="GoalLift.candidates"):
        RouteConfig(lift={"candidates": 0})
    with pytest.raises(ValueError, match="RouteConfig.lift"):
        RouteConfig(lift=3)
    with pytest.raises(ValueError, match="RouteRecovery.route must be a RouteConfig .no field wobble"):
        RouteRecovery(route={"samples": 10, "wobble": 1})  # a one-line error, not a TypeError
    # a recording's metadata holds the settings as nested dicts: they round-trip
    assert RouteRecovery(route=dataclasses.asdict(LIFT)).route == LIFT


def test_prepare_compiles_the_routes_programs_where_a_plan_is_due_so_the_plan_compiles_nothing(cloud):
    """The warm-up compiles the step alone; ``prepare`` compiles the route's programs before the step
    whose stall count makes a plan due (the one ``may_plan`` names), and nothing before the others."""
    mppi = _controller()
    programs = [route_module._clearance, route_module._refine, route_module._ends, route_module.around,
                controller_module._check_moves]
    for program in programs:  # so that each of them compiles here, whatever the tests before compiled
        program.clear_cache()
    before = [p._cache_size() for p in programs]
    state = mppi.init(jax.random.PRNGKey(0))
    mppi.warm_up(state, START, GOAL, cloud)
    mppi.prepare(_stalled(state, 4), START, GOAL, cloud)  # a plan is due at 6 steps without progress (after=5)
    assert [p._cache_size() for p in programs] == before
    due = _stalled(state, 5)
    assert mppi.may_plan(due) and not mppi.may_plan(_stalled(state, 4)) and not mppi.may_plan(_stalled(state, 6))
    mppi.prepare(due, START, GOAL, cloud)
    warm = [p._cache_size() for p in programs]
    assert all(w > b for w, b in zip(warm, before))
    _, after, _ = mppi.step(due, START, GOAL, cloud)
    assert after.route.routes == 1 and len(after.route.states) > 0  # a plan, its states in other counts than prepare's
    assert [p._cache_size() for p in programs] == warm


def test_the_approach_is_the_guided_paths_last_direction():
    """A field that is the straight distance to the goal: its descent runs straight to the goal, so
    the approach is the direction from the start, within the 26 neighbours' steps."""
    from ncedf.grid_model import padded
    from ncedf.guide import approach, descent

    h, goal = 0.1, np.array([2.0, 1.0, 1.5])
    centres = np.stack(np.meshgrid(*[np.arange(0, 26) * h] * 3, indexing="ij"), axis=-1)
    field = padded(np.zeros(3), h, np.linalg.norm(centres - goal, axis=-1).astype(np.float32), 26**3)
    for way in ([1.0, 0.0, 0.0], [1.0, 1.0, 1.0], [0.0, -1.0, 1.0]):  # lattice directions: straight descents
        expected = np.asarray(way) / np.linalg.norm(way)
        start = goal - 1.5 * expected
        path = descent(field, start)
        assert np.linalg.norm(path[-1] - goal) <= h * np.sqrt(3) / 2
        direction = approach(field, start, goal, 1.0)
        assert np.linalg.norm(direction) == pytest.approx(1.0) and np.degrees(np.arccos(direction @ expected)) < 2.0


def test_aligned_goal_states_and_their_retraction_chains_follow_the_approach(polytopes):
    """The aligned goal states arrive along the approach (tip axis) with their last link straight
    behind the tip; each chain state's tip lies on the line back from the goal, and is clear."""
    spec, goal, direction = RobotSpec(5), np.array([3.5, 0.0, 2.0]), np.array([1.0, 0.0, 0.0])  # under the bar
    config = dataclasses.replace(ROUTE, retract_steps=3, node_clearance=0.05, edge_clearance=0.05)
    drawn = np.asarray(sample_arc_lengths(jax.random.PRNGKey(2), spec, (600, 5)), np.float32)
    aligned = goal_states(drawn, goal, spec, polytopes, config, direction)
    assert len(aligned) > 10
    frames = np.asarray(jax.vmap(lambda a: route_module.forward_kinematics(a, spec))(jnp.asarray(aligned)))
    assert np.all(frames[:, -1, :3, 2] @ direction > np.cos(np.radians(12)))
    assert np.all(np.linalg.norm(frames[:, -2, :3, 3] - (frames[:, -1, :3, 3] - 2.0 * direction), axis=1) < 0.3)
    chains = route_module.retraction_chains(aligned, goal, direction, spec, polytopes, config)
    back = (goal - tips(chains, spec)) @ direction  # how far each tip was drawn back along the approach
    off_line = np.linalg.norm(goal - tips(chains, spec) - back[:, None] * direction, axis=1)
    assert len(chains) > 0 and np.all(np.isin(np.round(back / 0.2), [1, 2, 3])) and np.all(off_line < 0.2)
    assert np.all(clearances(chains, spec, polytopes) >= config.edge_clearance)


def test_a_position_goals_route_arrives_along_the_free_path_from_the_base(monkeypatch):
    """A slot between two dense slabs (x in [3, 6], open at both ends), the goal in its middle and the
    tip stalled above its far end: the free path from the tip would enter the slot from its far end
    (-x), the body's from the base enters it from the near end; the route's goal states arrive along
    the latter (+x)."""
    from ncedf.grid_model import GridModel
    from ncedf.guide import Guide
    from ncedf.mppi import MPPIState
    from ncedf.recovery import no_route, start_route

    xy = np.stack(np.meshgrid(np.arange(3.0, 6.01, 0.1), np.arange(-3.0, 3.01, 0.1)), -1).reshape(-1, 2)
    slabs = np.concatenate([np.column_stack([xy, np.full(len(xy), z)]) for z in (2.0, 3.2)]).astype(np.float32)
    goal = np.array([4.5, 0.0, 2.6])
    mask = np.ones(len(slabs), bool)
    grid = GridModel(0.1, 0.2).fit(slabs, mask, slabs, mask, 0.05, goal)
    field = Guide(0.2).fit(grid, goal)
    asked = []
    monkeypatch.setattr("ncedf.recovery.plan_route", lambda *args, **kwargs: asked.append(args[6]))
    spec = RobotSpec(n_links=5)
    stalled = config_to_arc_lengths(jnp.asarray([0.4, 0.4, 0.4, 0.3, 0.8]), jnp.zeros(5), spec)  # bent towards +x
    tip = np.asarray(end_effector_pose(stalled, spec))[:3, 3]
    assert tip[0] > 6.0 and tip[2] > 3.2  # above the far end
    mppi = MPPIState(*[None] * len(MPPIState._fields))._replace(key=jax.random.PRNGKey(0))
    start_route(RouteRecovery(), spec, no_route(spec), mppi, np.asarray(stalled), goal, grid, field)
    assert asked[0] @ np.array([1.0, 0.0, 0.0]) > 0.9


def test_after_each_plan_that_found_no_route_the_next_searches_a_larger_roadmap_and_tree(monkeypatch):
    """A plan after k plans that found no route draws ``growth`` ** k times the first plan's roadmap states
    and tree rounds; a plan that found one grows nothing; the other settings are the first plan's."""
    from ncedf.mppi import MPPIState
    from ncedf.recovery import no_route, start_route

    asked, found = [], iter([None, None, START[None].repeat(3, axis=0), None])
    monkeypatch.setattr("ncedf.recovery.plan_route", lambda *args, **kwargs: asked.append(args[5]) or next(found))
    box = np.random.default_rng(0).uniform([2.0, -0.5, 1.0], [2.5, 0.5, 2.0], (200, 3)).astype(np.float32)
    mask = np.ones(len(box), bool)
    model = ConvexModel(1.0).fit(box, mask, box, mask, 0.05)
    mppi = MPPIState(*[None] * len(MPPIState._fields))._replace(key=jax.random.PRNGKey(0), stalled=jnp.asarray(0),
                                                                best_goal=jnp.asarray(0.0))
    recovery, route = RouteRecovery(growth=3.0, route=LIFT), no_route(SPEC)
    for _ in range(4):
        route, _ = start_route(recovery, SPEC, route, mppi, START, GOAL, model)
    assert route.routes == 4 and route.failed == 3
    assert [c.samples for c in asked] == [LIFT.samples * f for f in (1, 3, 9, 9)]
    assert [c.bridge.rounds for c in asked] == [LIFT.bridge.rounds * f for f in (1, 3, 9, 9)]
    assert all(dataclasses.replace(c, samples=LIFT.samples, bridge=LIFT.bridge) == LIFT for c in asked)
