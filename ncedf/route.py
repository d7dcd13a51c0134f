"""A route in configuration space around static convex obstacles, for a robot that MPPI leaves stuck.

MPPI is local: where the way to the goal first leads away from it (a
goal right behind a box, reached through the gap
under it) every rollout's goal cost says stay, and the robot stalls in front of
the box. :func:`plan_route` finds the way round with a probabilistic roadmap
over arc lengths, checked against the convex model of the static obstacles
(``ncedf.convex``):

* nodes: the current state, ``samples`` random valid states
  (``ncedf.robot.sample_arc_lengths``) whose clearance to the polytopes
  (``ncedf.obstacle_model.model_clearance``, a lower bound of the body's; the
  grid model's too) is at least
  ``node_clearance``, ``local_samples`` states around the current one
  (:func:`around`) with at least ``edge_clearance``, and goal states: the
  ``goal_candidates`` free nodes whose end effectors lie nearest the goal,
  moved by ``goal_iterations`` damped least-squares steps on the tip error
  (:func:`_refine`; ``ncedf.robot.project_state`` keeps them valid), kept where the tip is within
  ``goal_tolerance`` of the goal and the clearance still ``node_clearance``;
* with an approach direction (the way into the goal, where the goal lies in an
  opening: ``ncedf.guide.approach``), aligned goal states too: the same
  candidates refined on the tip's position and its approach axis
  (``approach_weight``; the weighted axis error too within ``goal_tolerance``), and from
  each a retraction chain, its tip drawn back along the direction ``retract_step`` at a
  time for ``retract_steps`` steps
  (each state refined from the one before), the states kept where their
  clearance is ``edge_clearance``: a random state almost never threads an
  opening, and the chains lead out of it;
* edges: each node to its ``neighbours`` nearest (Euclidean in arc lengths;
  an edge where either node lists the other), kept where the states inside the
  segment, ``check_step`` apart in every arc length, have at least
  ``edge_clearance`` (the current state's own edges too: the robot may be
  closer than ``node_clearance`` where it stalled; where it stalled closer
  than ``edge_clearance`` and none of its edges passes, the route first
  moves to the state around it whose segment keeps the most clearance, never
  less than its own, and the roadmap starts there: :func:`way_out`). The body
  is that sensitive to its arc lengths: 0.01 m of change moves a joint by up to
  0.55 m with 4 links and 1.3 m with 7 (random states, p99 0.43 and 0.78 m).
  So the random nodes alone leave a robot stalled near a box unconnected
  (the fixed goal, 4 links, seed 1: its nearest 12 are 0.43-0.50 m away in arc
  lengths and every edge to them meets a box); the states around it bridge
  that gap;
* the shortest path (Dijkstra, length in arc lengths) from the current state
  to the nearest goal state, its edges checked lazily
  (:func:`lazy_shortest_path`: only those of the shortest paths tried, a few
  dozen of some 30 000 with 4 links), its detours cut (:func:`shortcut`: a
  straight segment in arc lengths moves the tip along a curve, so the
  roadmap's path wanders).
* where the roadmap holds no route (no goal state, or none connected), a second
  try with goal states lifted clear (:class:`GoalLift`): among obstacles a body
  refined onto the goal mostly lies in one, and climbing its soft clearance
  in the tip's null space finds the few clear ways to the goal.
* where that roadmap holds none either (the goal states in pockets of their
  own: a goal behind a pillar, whose nearest free states are all blocked from
  it), a third: a tree of short branches grown from the goal states until one
  links to the start's component of the roadmap (:class:`Bridge`,
  :func:`bridged_path`). A pose goal gets the first and the third, from its
  aligned goal states (a lifted state keeps the tip on the goal, not its axis).

The route is the path's states, ``path_step`` apart in every arc length. The
controller executes them (``ncedf.recovery``): each step's move along
them passes its safety check first, which sees the moving obstacles.

Host-side (numpy and scipy around jitted JAX), as the polytope fit is: it runs
once per stall, not per step. The states are scored ``PASS`` at a time (one
compiled program per robot and settings, which ``Controller.prepare`` compiles before the
timed step of a controller's first plan). Its time per plan: ``bench/route_plan.py``.
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
import jax
import jax.numpy as jnp
import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components, dijkstra
from scipy.spatial import cKDTree

from ncedf.convex import Polytopes
from ncedf.obstacle_model import model_clearance, soft_clearance
from ncedf.robot import RobotSpec, end_effector_pose, forward_kinematics, project_state, sample_arc_lengths
from ncedf.validate import check_fields, nested

#: States per jitted clearance call (padded), so every call reuses one program.
PASS = 4096
#: Inner states of the edges checked in one batch (``edge_clearances``): 64 passes, a few tens of MB.
EDGE_BATCH = 64 * PASS


@dataclasses.dataclass(frozen=True)
class GoalLift:
    """The roadmap's second try (:func:`plan_route`): the ``candidates`` free states nearest the goal,
    refined on the tip, then ``iterations`` more refinement steps, each also moving the state ``step`` m
    (its largest arc length change) up the gradient of its soft clearance
    (``ncedf.obstacle_model.soft_clearance``) within the tip's null space, so that bodies refined
    into an obstacle climb out of it while the tip stays on the goal."""

    candidates: int = 3000
    iterations: int = 200
    step: float = 0.02

    def __post_init__(self):
        check_fields(self, integers=("candidates", "iterations"), positive=("step",))


@dataclasses.dataclass(frozen=True)
class Bridge:
    """The roadmap's third try (:func:`plan_route`): a tree grown from the goal states, ``rounds`` rounds
    of ``batch`` branches, each from the tree's state nearest a target (a free state, or a fresh random
    one, half and half) ``step`` m towards it (its largest arc change), kept where the branch is clear;
    it stops once a new state has a clear edge to one of its ``links`` nearest free states."""

    rounds: int = 1000
    batch: int = 80
    step: float = 0.03
    links: int = 3

    def __post_init__(self):
        check_fields(self, integers=("rounds", "batch", "links"), positive=("step",))


@dataclasses.dataclass(frozen=True)
class RouteConfig:
    """Settings of :func:`plan_route` (module docstring).

    Attributes:
      samples: random states drawn for the roadmap.
      local_samples, local_radius: states drawn around the current one, each arc length moved by at
        most ``local_radius`` m (:func:`around`).
      neighbours: edges tried per node.
      check_step: the most any arc length changes between checked states of an edge, m. Equal to
        ``path_step`` (the default), every state of the route is a checked one; coarser, the body can
        swing into an obstacle between two checked states and the safety check refuses the route there.
      node_clearance: least clearance of a node, m.
      edge_clearance: least clearance along an edge, m.
      goal_candidates: free nodes refined towards the goal.
      goal_iterations, goal_damping, goal_move: damped least-squares steps on the tip error
        (:func:`_refine`), their damping (m) and the most one moves an arc length (m).
      goal_tolerance: a goal state's tip is this close to the goal, m.
      approach_weight: an aligned goal state's weight of its approach-axis error (m per unit).
      retract_step, retract_steps: the retraction chains' steps, m, and their number.
      approach_back: the approach direction is that of the guided path's last ``approach_back`` m
        (``ncedf.guide.approach``).
      path_step: the most any arc length changes between the path's states, m.
      lazy_rounds: rounds of :func:`lazy_shortest_path` before it checks every edge left (1: every edge
        checked after the first search, as if all were checked first).
      lift: the goal states of the second try, where the first finds no route (:class:`GoalLift`, or
        its fields as a dict).
      bridge: the third try's tree from the goal states, where the earlier tries find no route
        (:class:`Bridge`, or its fields as a dict).
    """

    samples: int = 5000
    local_samples: int = 1000
    local_radius: float = 0.1
    neighbours: int = 12
    check_step: float = 0.002
    node_clearance: float = 0.25
    edge_clearance: float = 0.2
    goal_candidates: int = 300
    goal_iterations: int = 20
    goal_damping: float = 0.05
    goal_move: float = 0.05
    goal_tolerance: float = 0.2
    approach_weight: float = 1.0
    retract_step: float = 0.2
    retract_steps: int = 12
    approach_back: float = 1.0
    path_step: float = 0.002
    lazy_rounds: int = 50
    lift: GoalLift = GoalLift()
    bridge: Bridge = Bridge()

    def __post_init__(self):
        nested(self, "lift", GoalLift)
        nested(self, "bridge", Bridge)
        check_fields(self, integers=("samples", "local_samples", "neighbours", "goal_candidates", "goal_iterations",
                                     "lazy_rounds", "retract_steps"),
                     positive=("local_radius", "check_step", "node_clearance", "edge_clearance", "goal_damping",
                               "goal_move", "goal_tolerance", "approach_weight", "retract_step", "approach_back",
                               "path_step"))


def grown(config: RouteConfig, factor: float) -> RouteConfig:
    """``config`` with ``factor`` times its roadmap's random states and its tree's rounds (rounded)."""
    rounds = max(1, round(config.bridge.rounds * factor))
    return dataclasses.replace(config, samples=max(1, round(config.samples * factor)),
                               bridge=dataclasses.replace(config.bridge, rounds=rounds))


@functools.partial(jax.jit, static_argnums=1)
def _clearance(arcs: jnp.ndarray, spec: RobotSpec, polytopes: Polytopes) -> jnp.ndarray:
    """(PASS,) clearance of (PASS, M, 3) states to the polytopes, m."""
    return model_clearance(polytopes, arcs, forward_kinematics(arcs, spec), spec)


def _in_passes(program, arcs: np.ndarray, row: tuple[int, ...], *args) -> np.ndarray:
    """(N, *row) float32: ``program(states, *args)`` of (N, M, 3) states, ``PASS`` at a time (the last pass padded
    with its last state), so one compiled program serves every N."""
    out = np.empty((len(arcs),) + row, np.float32)
    for start in range(0, len(arcs), PASS):
        part = arcs[start:start + PASS]
        padded = np.concatenate([part, np.repeat(part[-1:], PASS - len(part), axis=0)])
        out[start:start + len(part)] = np.asarray(program(jnp.asarray(padded, jnp.float32), *args))[:len(part)]
    return out


def clearances(arcs: np.ndarray, spec: RobotSpec, polytopes: Polytopes) -> np.ndarray:
    """(N,) clearance of (N, M, 3) states to the polytopes (a lower bound of the body's), m."""
    return _in_passes(_clearance, arcs, (), spec, polytopes)


@functools.partial(jax.jit, static_argnums=(2, 3, 4))
def around(start: jnp.ndarray, key, spec: RobotSpec, count: int, radius: float) -> jnp.ndarray:
    """(count, M, 3) valid states around ``start`` (M, 3): each moved by ``radius`` m times a uniform factor in
    [0, 1] times a uniform direction in the box [-1, 1]^(M x 3), then projected onto the valid states."""
    direction = jax.random.uniform(jax.random.fold_in(key, 0), (count,) + start.shape, minval=-1.0, maxval=1.0)
    scale = radius * jax.random.uniform(jax.random.fold_in(key, 1), (count, 1, 1))
    return jax.vmap(lambda arc: project_state(arc, spec))(start + scale * direction)


@functools.partial(jax.jit, static_argnums=(2, 3, 4, 5, 7, 8))
def _refine(arcs: jnp.ndarray, goal: jnp.ndarray, spec: RobotSpec, iterations: int, damping: float,
            move: float, approach=None, weight: float = 0.0, climb: float = 0.0, fitted=None) -> jnp.ndarray:
    """States ``arcs`` (K, M, 3), m, moved towards a tip at ``goal`` (3,) m by damped least squares
    (Levenberg-Marquardt with a fixed damping): each iteration moves a state by
    ``-J^T (J J^T + damping^2 I)^-1 e``, with e the tip error (3,) and J (3, 3M) the tip's Jacobian
    on arc changes that keep each link's sum, scaled so that no arc length moves more than ``move``
    m, then projected onto the valid states. With an ``approach`` (3,) unit vector, e also holds
    ``weight`` times the errors of the tip's approach axis (its z axis) and of the last link's base
    from a link's length straight behind the tip along it. With a ``fitted`` model, each iteration
    also moves the state ``climb`` m (its largest arc change) up the gradient of its soft clearance
    to the model, less the part the damped tip Jacobian would turn into tip motion."""
    keep_sum = jnp.eye(3) - 1.0 / 3.0  # projector onto a link's zero-sum changes

    def error(arc):
        frames = forward_kinematics(arc, spec)
        tip = frames[-1, :3, 3]
        if approach is None:
            return tip - goal
        last = frames[-2, :3, 3] - (tip - spec.length * approach)  # the last link straight along it
        return jnp.concatenate([tip - goal, weight * (frames[-1, :3, 2] - approach), weight * last])

    def one(arc):
        e = error(arc)
        jac = (jax.jacfwd(error)(arc) @ keep_sum).reshape(len(e), -1)  # (3 or 9, 3M)
        gram = jac @ jac.T + damping**2 * jnp.eye(len(e))
        delta = -jac.T @ jnp.linalg.solve(gram, e)
        delta = delta * jnp.minimum(1.0, move / jnp.maximum(jnp.max(jnp.abs(delta)), 1e-12))
        if fitted is not None:
            grad = jax.grad(lambda a: soft_clearance(fitted, a, forward_kinematics(a, spec), spec))(arc)
            grad = (jnp.where(jnp.isfinite(grad), grad, 0.0) @ keep_sum).reshape(-1)
            up = grad - jac.T @ jnp.linalg.solve(gram, jac @ grad)
            delta = delta + climb * up / jnp.maximum(jnp.max(jnp.abs(up)), 1e-12)
        return project_state(arc + delta.reshape(arc.shape), spec)

    return jax.lax.fori_loop(0, iterations, lambda _, q: jax.vmap(one)(q), arcs)


@functools.partial(jax.jit, static_argnums=1)
def _ends(arcs: jnp.ndarray, spec: RobotSpec) -> jnp.ndarray:
    return end_effector_pose(arcs, spec)[..., :3, 2:]


def ends(arcs: np.ndarray, spec: RobotSpec) -> tuple[np.ndarray, np.ndarray]:
    """The end effectors of (N, M, 3) states: approach axes (N, 3) and positions (N, 3), m."""
    both = _in_passes(_ends, np.asarray(arcs, np.float32), (3, 2), spec).astype(np.float64)
    return both[..., 0], both[..., 1]


def tips(arcs: np.ndarray, spec: RobotSpec) -> np.ndarray:
    """(N, 3) end-effector positions of (N, M, 3) states, m."""
    return ends(arcs, spec)[1]


def _refined(states: np.ndarray, goal: np.ndarray, spec: RobotSpec, config: RouteConfig, approach=None,
             size: int | None = None, fitted=None) -> np.ndarray:
    """:func:`_refine` of up to ``size`` (default ``goal_candidates``) states (K, M, 3), padded to that many
    (one program); with a ``fitted`` model, the lift's iterations climbing clear of it (:class:`GoalLift`)."""
    padded = np.zeros((size or config.goal_candidates,) + states.shape[1:], np.float32)
    padded[:len(states)] = states
    padded[len(states):] = states[:1]
    direction = None if approach is None else jnp.asarray(approach, jnp.float32)
    iterations, climb = (config.goal_iterations, 0.0) if fitted is None else (config.lift.iterations, config.lift.step)
    return np.asarray(_refine(jnp.asarray(padded), jnp.asarray(goal, jnp.float32), spec, iterations,
                              config.goal_damping, config.goal_move, direction, config.approach_weight, climb,
                              fitted))[:len(states)]


def goal_states(free: np.ndarray, goal: np.ndarray, spec: RobotSpec, polytopes: Polytopes,
                config: RouteConfig, approach=None, lifted: bool = False) -> np.ndarray:
    """(G, M, 3) states whose tips are within ``goal_tolerance`` of ``goal`` and whose clearance is at least
    ``node_clearance``: the free states (F, M, 3) nearest the goal, refined (module docstring), on the tip
    and, given an ``approach`` (3,) unit vector, on its approach axis too; ``lifted``: the lift's
    candidates, refined on the tip, then lifted clear of the polytopes (:class:`GoalLift`)."""
    size = config.lift.candidates if lifted else config.goal_candidates
    near = np.argsort(np.linalg.norm(tips(free, spec) - goal, axis=1))[:size]
    moved = _refined(free[near], goal, spec, config, approach, size)
    if lifted:
        moved = _refined(moved, goal, spec, config, approach, size, polytopes)
    axes, reached = ends(moved, spec)
    ok = ((np.linalg.norm(reached - goal, axis=1) <= config.goal_tolerance)
          & (clearances(moved, spec, polytopes) >= config.node_clearance))
    if approach is not None:  # and the weighted error of the approach axis within the tolerance too
        ok &= config.approach_weight * np.linalg.norm(axes - approach, axis=1) <= config.goal_tolerance
    return moved[ok]


def retraction_chains(targets: np.ndarray, goal: np.ndarray, approach: np.ndarray, spec: RobotSpec,
                      polytopes: Polytopes, config: RouteConfig) -> np.ndarray:
    """(C, M, 3) the states of the chains from the aligned goal states ``targets`` (G, M, 3) back along
    ``approach`` (module docstring) that are clear and whose tips lie within ``goal_tolerance`` of
    their step's target; none without targets."""
    if len(targets) == 0:
        return targets
    chain, current = [], targets[:config.goal_candidates]
    for k in range(1, config.retract_steps + 1):
        target = goal - k * config.retract_step * approach
        current = _refined(current, target, spec, config, approach)
        kept = ((clearances(current, spec, polytopes) >= config.edge_clearance)
                & (np.linalg.norm(tips(current, spec) - target, axis=1) <= config.goal_tolerance))
        chain.append(current[kept])
    return np.concatenate(chain)


def bridge(goals: np.ndarray, free: np.ndarray, spec: RobotSpec, polytopes: Polytopes, config: RouteConfig,
           key) -> tuple[int, np.ndarray]:
    """A chain from one of the states ``free`` (F, M, 3) to a goal state of ``goals`` (G, M, 3), every
    segment clear (``edge_clearance``): (that free state's index, the (C, M, 3) states after it). A tree
    grows from the goal states (:class:`Bridge`) until a new state has a clear edge to a free state; the
    chain is the new state and its branches back to the goal state they grew from. (-1, none) where no
    round links. Where a goal state's nearest free states are all blocked from it (a goal behind a
    pillar), short branches find the few ways between."""
    grow = config.bridge
    if len(goals) == 0 or len(free) == 0:
        return -1, goals[:0]
    tree, parent = np.asarray(goals, np.float32), np.full(len(goals), -1)
    flat_free = cKDTree(free.reshape(len(free), -1))
    for round_ in range(grow.rounds):
        keys = jax.random.split(jax.random.fold_in(key, round_), 2)
        fresh = np.asarray(sample_arc_lengths(keys[0], spec, (grow.batch // 2, spec.n_links)), np.float32)
        picked = np.asarray(jax.random.randint(keys[1], (grow.batch - grow.batch // 2,), 0, len(free)))
        targets = np.concatenate([free[picked], fresh])
        near = cKDTree(tree.reshape(len(tree), -1)).query(targets.reshape(len(targets), -1))[1]
        move = targets - tree[near]
        scale = np.minimum(1.0, grow.step / np.maximum(np.abs(move).max(axis=(1, 2)), 1e-9))
        new = tree[near] + move * scale[:, None, None]
        clear = clear_edges(tree[near], new, spec, polytopes, config) & (
            clearances(new, spec, polytopes) >= config.edge_clearance)
        tree, parent = np.concatenate([tree, new[clear]]), np.concatenate([parent, near[clear]])
        if not clear.any():
            continue
        added = np.arange(len(tree) - clear.sum(), len(tree))
        k = min(grow.links, len(free))
        nearest = flat_free.query(tree[added].reshape(len(added), -1), k)[1].reshape(len(added), k)
        linked = clear_edges(np.repeat(tree[added], k, axis=0), free[nearest.ravel()], spec, polytopes, config)
        if linked.any():
            first = int(np.argmax(linked))
            chain = [int(added[first // k])]
            while parent[chain[-1]] >= 0:
                chain.append(int(parent[chain[-1]]))
            return int(nearest.ravel()[first]), tree[chain]
    return -1, goals[:0]


def segment_parts(a: np.ndarray, b: np.ndarray, step: float) -> np.ndarray:
    """(E,) the parts each segment from a to b (E, M, 3) is cut into, at most ``step`` apart in every arc length."""
    return np.maximum(np.ceil(np.max(np.abs(b - a), axis=(1, 2)) / step).astype(int), 1)


def between(a: np.ndarray, b: np.ndarray, step: float) -> tuple[np.ndarray, np.ndarray]:
    """The states strictly inside the segments from a to b (E, M, 3), at most ``step`` apart in every arc
    length: ((S, M, 3) states, (S,) their segment's index), segment by segment."""
    parts = segment_parts(a, b, step)
    edge = np.repeat(np.arange(len(a)), parts - 1)
    first = np.repeat(np.cumsum(parts - 1) - (parts - 1), parts - 1)
    t = ((np.arange(len(edge)) - first + 1) / np.repeat(parts, parts - 1))[:, None, None]
    return (a[edge] * (1 - t) + b[edge] * t).astype(np.float32), edge


def edge_clearances(a: np.ndarray, b: np.ndarray, spec: RobotSpec, polytopes: Polytopes, step: float) -> np.ndarray:
    """(E,) the least clearance inside each segment from a to b (E, M, 3), checked ``step`` apart, m; the
    segments taken a batch of at most ``EDGE_BATCH`` inner states at a time (one segment at least), so that
    checking every edge of a roadmap at once holds a batch's states in memory, not all of them."""
    before = np.concatenate([[0], np.cumsum(segment_parts(a, b, step) - 1)])
    clear = np.full(len(a), np.inf, np.float32)
    start = 0
    while start < len(a):
        stop = max(start + 1, int(np.searchsorted(before, before[start] + EDGE_BATCH, side="right")) - 1)
        along, edge = between(a[start:stop], b[start:stop], step)
        np.minimum.at(clear, start + edge, clearances(along, spec, polytopes))
        start = stop
    return clear


def way_out(start: np.ndarray, around_start: np.ndarray, spec: RobotSpec, polytopes: Polytopes,
            config: RouteConfig) -> np.ndarray | None:
    """Where the roadmap starts: ``start`` (M, 3) itself where its clearance is ``edge_clearance`` or more, or
    where a segment to one of the states ``around_start`` (L, M, 3) keeps it. Else (a robot stalled nearer,
    pressed against a surface: none of its edges would pass the check) the state around it whose segment
    keeps the most clearance, if that is never less than the start's own: the route first moves there,
    never nearer the obstacles than it is. None where no segment does."""
    now = clearances(start[None], spec, polytopes)[0]
    if now >= config.edge_clearance:
        return start
    if len(around_start) == 0:
        return None
    along = edge_clearances(np.repeat(start[None], len(around_start), axis=0), around_start, spec, polytopes,
                            config.check_step)
    best = int(np.argmax(along))
    if along[best] >= config.edge_clearance:
        return start
    return around_start[best] if along[best] >= now else None


def clear_edges(a: np.ndarray, b: np.ndarray, spec: RobotSpec, polytopes: Polytopes, config: RouteConfig) -> np.ndarray:
    """(E,) bool: whether each segment from a to b (E, M, 3) keeps ``edge_clearance`` (:func:`edge_clearances`,
    checked ``check_step`` apart)."""
    return edge_clearances(a, b, spec, polytopes, config.check_step) >= config.edge_clearance


def shortcut(path: np.ndarray, spec: RobotSpec, polytopes: Polytopes, config: RouteConfig) -> np.ndarray:
    """(Q, M, 3) the roadmap path (P, M, 3) with its detours cut: from each kept node, straight to the last
    node whose segment from it is clear (``edge_clearance``); the next node always is (a roadmap edge)."""
    kept = [0]
    while kept[-1] < len(path) - 1:
        later = np.arange(len(path) - 1, kept[-1], -1)
        ok = clear_edges(np.repeat(path[kept[-1]][None], len(later), axis=0), path[later], spec, polytopes, config)
        kept.append(int(later[np.argmax(ok)]) if ok.any() else kept[-1] + 1)
    return path[kept]


def roadmap_edges(nodes: np.ndarray, neighbours: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The roadmap's edges over (N, M, 3) nodes: each node to its ``neighbours`` nearest (Euclidean in arc
    lengths), once whichever of its two nodes lists the other: (i, j) (E,) with i < j and lengths w (E,)."""
    flat = nodes.reshape(len(nodes), -1)
    k = min(neighbours, len(nodes) - 1)
    length, near = cKDTree(flat).query(flat, k + 1)
    i, j, w = np.repeat(np.arange(len(nodes)), k), near[:, 1:].ravel(), length[:, 1:].ravel()
    i, j = np.minimum(i, j), np.maximum(i, j)
    _, once = np.unique(i * len(nodes) + j, return_index=True)
    return i[once], j[once], w[once]


def shortest_path(count: int, i: np.ndarray, j: np.ndarray, w: np.ndarray, ends: np.ndarray) -> list[int] | None:
    """The node indices of the shortest path from node 0 to the nearest of ``ends`` over the undirected edges
    (i, j) (E,) of lengths w (E,) among ``count`` nodes (Dijkstra), or None when no end is reached."""
    graph = coo_matrix((w, (i, j)), shape=(count, count))
    dist, previous = dijkstra(graph, directed=False, indices=0, return_predecessors=True)
    reached = ends[np.isfinite(dist[ends])]
    if len(reached) == 0:
        return None
    path = [int(reached[np.argmin(dist[reached])])]
    while path[-1] != 0:
        path.append(int(previous[path[-1]]))
    return path[::-1]


def lazy_shortest_path(nodes: np.ndarray, i: np.ndarray, j: np.ndarray, w: np.ndarray, goals: int, spec: RobotSpec,
                       polytopes: Polytopes, config: RouteConfig, checked: dict | None = None) -> list[int] | None:
    """The node indices of the shortest path from node 0 to any of the last ``goals`` nodes (N, M, 3) over the
    edges (i, j) (E,) of lengths w (E,) that are clear (``edge_clearance``, checked ``check_step`` apart), or
    None when no such path exists.

    Lazily: the shortest path over the edges not yet found blocked, its unchecked edges checked, repeated until
    a path's edges are all clear. That path is the shortest over the clear edges, as if every edge had been
    checked first, and a route usually checks a few dozen edges instead of tens of thousands. After
    ``lazy_rounds`` rounds the edges still unchecked are checked at once, which bounds the rounds where no
    path exists. ``checked``: the edges (a, b) (node indices, a < b) known already, 1 clear or -1 blocked,
    updated with those checked here, so that a search over more nodes after these (the same first ones)
    checks no edge twice."""
    checked = {} if checked is None else checked
    pairs = list(zip(i.tolist(), j.tolist()))
    clear = np.array([checked.get(pair, 0) for pair in pairs], np.int8)  # 1 clear, -1 blocked, 0 not checked yet
    index = {pair: e for e, pair in enumerate(pairs)}
    ends = np.arange(len(nodes) - goals, len(nodes))
    for round_ in itertools.count(1):
        kept = clear >= 0
        path = shortest_path(len(nodes), i[kept], j[kept], w[kept], ends)
        if path is None:
            return None
        edges = np.asarray([index[min(a, b), max(a, b)] for a, b in zip(path[:-1], path[1:])], int)
        if np.all(clear[edges] == 1):
            return path
        unknown = edges[clear[edges] == 0] if round_ < config.lazy_rounds else np.flatnonzero(clear == 0)
        clear[unknown] = np.where(clear_edges(nodes[i[unknown]], nodes[j[unknown]], spec, polytopes, config), 1, -1)
        checked.update(zip(zip(i[unknown].tolist(), j[unknown].tolist()), clear[unknown].tolist()))


def roadmap_path(others: np.ndarray, targets: np.ndarray, spec: RobotSpec, polytopes: Polytopes,
                 config: RouteConfig, checked: dict | None = None) -> np.ndarray | None:
    """(P, M, 3) the roadmap's shortest clear path from ``others[0]`` through the nodes ``others`` (N, M, 3) to
    one of ``targets`` (G, M, 3) (:func:`lazy_shortest_path`, its ``checked`` edges), or None where there is
    none."""
    if len(targets) == 0:
        return None
    nodes = np.concatenate([others, targets])
    i, j, w = roadmap_edges(nodes, config.neighbours)
    path = lazy_shortest_path(nodes, i, j, w, len(targets), spec, polytopes, config, checked)
    return None if path is None else nodes[path]


def bridged_path(others: np.ndarray, targets: np.ndarray, spec: RobotSpec, polytopes: Polytopes,
                 config: RouteConfig, checked: dict, key) -> np.ndarray | None:
    """(P, M, 3) a path from ``others[0]`` over the roadmap of the nodes ``others`` (N, M, 3) to a node that
    :func:`bridge` links to one of the goal states ``targets`` (G, M, 3), then the bridge; None where it
    links none. The roadmap's edges all checked (those in ``checked`` known already), so that the bridge
    links only to the start's component."""
    i, j, w = roadmap_edges(others, config.neighbours)
    known = np.array([checked.get(pair, 0) for pair in zip(i.tolist(), j.tolist())], np.int8)
    clear, unknown = known == 1, known == 0
    clear[unknown] = clear_edges(others[i[unknown]], others[j[unknown]], spec, polytopes, config)
    graph = coo_matrix((w[clear], (i[clear], j[clear])), shape=(len(others), len(others)))
    component = connected_components(graph, directed=False)[1]
    reached = np.flatnonzero(component == component[0])
    end, chain = bridge(targets, others[reached], spec, polytopes, config, key)
    if end < 0:
        return None
    path = shortest_path(len(others), i[clear], j[clear], w[clear], reached[[end]])
    return np.concatenate([others[path], chain])


def plan_route(spec: RobotSpec, polytopes: Polytopes, start, goal, key, config: RouteConfig = RouteConfig(),
               approach=None, aligned_only: bool = False) -> np.ndarray | None:
    """(S, M, 3) the states of a route from the state ``start`` (M, 3) m to one whose tip reaches ``goal`` (3,) m,
    clear of the polytopes, ``path_step`` apart (module docstring), or None when the roadmap holds none.
    ``key``: jax.random key of the samples; ``approach``: None or the unit vector (3,) the tip should
    arrive along (aligned goal states and their retraction chains); ``aligned_only``: the route must
    end in an aligned goal state (the approach axis is part of the goal: a pose)."""
    start = np.asarray(start, np.float32)
    goal = np.asarray(goal, np.float64)
    drawn = np.asarray(sample_arc_lengths(key, spec, (config.samples, spec.n_links)), np.float32)
    free = drawn[clearances(drawn, spec, polytopes) >= config.node_clearance]
    if len(free) == 0:
        return None
    chains = free[:0]  # none without an approach
    targets = free[:0] if aligned_only else goal_states(free, goal, spec, polytopes, config)
    if approach is not None:
        aligned = goal_states(free, goal, spec, polytopes, config, np.asarray(approach, np.float64))
        chains = retraction_chains(aligned, goal, np.asarray(approach, np.float64), spec, polytopes, config)
        targets = np.concatenate([targets, aligned])
    local = np.asarray(around(jnp.asarray(start), jax.random.fold_in(key, 1), spec, config.local_samples,
                              config.local_radius), np.float32)
    local = local[clearances(local, spec, polytopes) >= config.edge_clearance]
    first = way_out(start, local, spec, polytopes, config)
    if first is None:
        return None
    others = np.concatenate([first[None], free, local, chains])
    checked = {}  # the second try's nodes begin with the first's: their edges are checked once
    path = roadmap_path(others, targets, spec, polytopes, config, checked)
    if path is None and not aligned_only:  # the second try: goal states lifted clear of the obstacles
        targets = np.concatenate([targets, goal_states(free, goal, spec, polytopes, config, lifted=True)])
        path = roadmap_path(others, targets, spec, polytopes, config, checked)
    if path is None and len(targets):  # the third: a tree from the goal states (a pose's: the aligned ones)
        path = bridged_path(others, targets, spec, polytopes, config, checked, jax.random.fold_in(key, 2))
    if path is None:
        return None
    path = shortcut(path, spec, polytopes, config)
    if first is not start:
        path = np.concatenate([start[None], path])
    inner, segment = between(path[:-1], path[1:], config.path_step)
    order = np.argsort(np.concatenate([segment + 0.5, np.arange(len(path))]), kind="stable")
    return np.concatenate([inner, path])[order]
