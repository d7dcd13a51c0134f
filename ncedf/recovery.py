"""The recovery stage: a route round the static obstacles for a robot that MPPI leaves stuck.

MPPI is local: where the way to a goal first leads away from it (a goal right behind a
box) every rollout's goal cost says stay, and the robot stalls. :func:`supervise` runs
around the jitted MPPI step, the way a brax wrapper runs around an environment's step:
when the core's stall count reaches ``after`` + 1, and again every ``after`` steps while
it grows (at most ``tries`` plans per episode; after each plan that found no route the
next draws ``growth`` times the roadmap states and tree rounds), it plans a route from
the current state round the obstacle model's static polytopes (``ncedf.route``; the
moving ones are left out) or its grid, unless the model left a static cluster out as not
convex (the roadmap would not see that obstacle). Its goal states arrive along the
goal's approach axis where the goal is a pose, else, with the guide's field, along the
guided path from the robot's base (``ncedf.guide.approach``): the body runs from the
base to the goal, so it arrives the way free space leads from the base, whichever way
the stalled tip would have gone on. Where the roadmap holds none, nothing changes. Else
it executes the route: each step moves to the farthest route state within one step's
bound (or towards the next, at the bound) if that move passes the safety check, which
sees the moving obstacles too; else it holds if holding passes, else it takes MPPI's own
action. MPPI keeps planning underneath and takes over at the route's end, with a fresh
stall count. A route whose next move the check refuses for ``after`` steps in a row is
given up (its remaining states may pass the obstacle model's clearance but not the
check's distance to the points): MPPI steers again and the stall count, still growing,
calls the next plan.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ncedf.guide import approach
from ncedf.mppi import MPPIState
from ncedf.obstacle_model import left_out, static_part
from ncedf.robot import BASE, RobotSpec
from ncedf.route import RouteConfig, grown, plan_route
from ncedf.validate import check_fields, nested

#: Route states kept (a longer route is thinned evenly).
ROUTE_CAPACITY = 1024
#: Folded into the MPPI state's key for a route's samples.
ROUTE_SALT = 0x726F7574


@dataclasses.dataclass(frozen=True)
class RouteRecovery:
    """A route after ``after`` steps without progress, at most ``tries`` per episode; ``route``:
    the first plan's settings (``ncedf.route.RouteConfig``, or its fields as a dict, as a
    recording's metadata holds them); a later plan draws ``growth`` times the roadmap states
    and tree rounds for each plan before it that found no route (``ncedf.route.grown``)."""

    after: int = 30
    tries: int = 3
    route: RouteConfig = RouteConfig()
    growth: float = 2.0

    def __post_init__(self):
        check_fields(self, integers=("after", "tries"), positive=("growth",))
        nested(self, "route", RouteConfig)


class RouteState(NamedTuple):
    """The route being followed: its states (K, M, 3) m (K = 0: none), the index of the last one
    reached, the plans so far, the steps in a row its next move was refused, and the plans so far
    that found no route."""

    states: np.ndarray
    at: int
    routes: int
    blocked: int = 0
    failed: int = 0


def no_route(spec: RobotSpec) -> RouteState:
    """No route yet."""
    return RouteState(np.zeros((0, spec.n_links, 3), np.float32), 0, 0)


def _fresh_progress(mppi: MPPIState) -> MPPIState:
    return mppi._replace(stalled=jnp.asarray(0, jnp.int32), best_goal=jnp.asarray(jnp.inf, jnp.float32))


def plan_due(recovery: RouteRecovery, route: RouteState, stalled: int) -> bool:
    """Whether a plan is due where no route is being followed: the stall count is ``after`` + 1,
    2 ``after`` + 1, ..., and plans are left."""
    return stalled > recovery.after and (stalled - 1) % recovery.after == 0 and route.routes < recovery.tries


def start_route(recovery: RouteRecovery, spec: RobotSpec, route: RouteState, mppi: MPPIState, arc, goal,
                model, guide=None) -> tuple[RouteState, MPPIState]:
    """Plan a route from ``arc`` (M, 3) to ``goal`` round the still part of the fitted obstacle model
    (``ncedf.obstacle_model.static_part``): to a pose (4, 4) along its approach axis (its z axis), to
    a position (3,) along the guide's path from the base where there is a guide (``ncedf.guide.approach``)."""
    arc, goal = np.asarray(arc), np.asarray(goal)
    pose = goal.shape == (4, 4)
    if pose:
        goal, direction = goal[:3, 3], goal[:3, 2]
    else:
        direction = None if guide is None else approach(guide, BASE, goal, recovery.route.approach_back)
    config = grown(recovery.route, recovery.growth**route.failed)
    path = plan_route(spec, static_part(model), arc, goal, jax.random.fold_in(mppi.key, ROUTE_SALT), config,
                      direction, aligned_only=pose)
    if path is None:  # the stall count goes on, and with it the stall escape
        return route._replace(routes=route.routes + 1, failed=route.failed + 1), mppi
    keep = np.unique(np.linspace(0, len(path) - 1, ROUTE_CAPACITY).round().astype(int))
    return RouteState(path[keep].astype(np.float32), 0, route.routes + 1, failed=route.failed), _fresh_progress(mppi)


def route_move(route: RouteState, arc: np.ndarray, control_bound: float, dt: float) -> tuple[np.ndarray, int]:
    """The rates (M, 3) m/s to the farthest route state within one step at ``control_bound`` (m/s)
    of ``arc`` in every arc length, or towards the next one at the bound, and that state's index."""
    step_bound = control_bound * dt
    reached, end = route.at, len(route.states)
    while reached + 1 < end and np.max(np.abs(route.states[reached + 1] - arc)) <= step_bound:
        reached += 1
    u = (route.states[max(reached, route.at + 1)] - arc) / dt
    u = u - u.mean(axis=-1, keepdims=True)  # zero-sum per link, as every state's chambers
    # One scale for every link (not a per-link projection), so the move stays on the route's segment.
    u = u * min(1.0, control_bound / max(float(np.max(np.abs(u))), 1e-12))
    return u, reached


def supervise(recovery: RouteRecovery, spec: RobotSpec, check_moves, margin: float, control_bound: float,
              dt: float, route: RouteState, mppi: MPPIState, arc, goal, model, action, guide=None):
    """The action and states after MPPI's step (module docstring): a route's next move when one is
    followed or a plan is due, else MPPI's ``action``.

    Args:
      check_moves: ``moves (2, M, 3) -> (2,)`` clearance over the step, m.
      margin: the clearance a move needs, m.
      mppi: the state after MPPI's step.  arc: (M, 3) m.  goal: position (3,) or pose (4, 4), m.
      guide: the guide's field or None.
    Returns:
      (action (M, 3) m/s, RouteState, MPPIState).
    """
    if route.at >= len(route.states) - 1:
        if not plan_due(recovery, route, int(mppi.stalled)) or left_out(model):
            return action, route, mppi  # no plan where the model misses an obstacle: the roadmap would not see it
        route, mppi = start_route(recovery, spec, route, mppi, arc, goal, model, guide)
        if route.at >= len(route.states) - 1:
            return action, route, mppi
    u, reached = route_move(route, np.asarray(arc), control_bound, dt)
    moves = jnp.asarray(np.stack([u, np.zeros_like(u)]), jnp.float32)  # along the route, or hold
    clear = np.asarray(check_moves(moves))
    if clear[0] >= margin:
        if reached == len(route.states) - 1:  # the route's end: MPPI again, with a fresh stall count
            mppi = _fresh_progress(mppi)
        return moves[0], route._replace(at=reached, blocked=0), mppi
    if route.blocked + 1 >= recovery.after:  # given up: MPPI steers, the stall count goes on
        return action, no_route(spec)._replace(routes=route.routes, failed=route.failed), mppi
    return (moves[1] if clear[1] >= margin else action), route._replace(blocked=route.blocked + 1), mppi
