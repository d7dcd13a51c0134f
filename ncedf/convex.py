"""A convex model of an obstacle cloud: its clusters of static and of moving points as polytopes.

A cloud sampled at a few points per square metre on obstacle surfaces has holes
wider than the robot (up to 0.8 m across at the paper's 4
points per m^2), and a distance to the points alone lets a link slide into a
face between them. Where the obstacles are convex (the paper's boxes)
their surfaces can be closed from the points alone:

* static and moving points: the rows of the cloud that did not move since the
  previous step, and the others (:func:`static_rows`; the scenarios observe
  row ``i`` as the same physical point at every step, so a moving obstacle's
  rows change; at the first step every row counts as moving);
* clusters: single linkage among the static and among the moving points:
  points closer than ``link`` are on one obstacle, and so are clusters whose
  bounding boxes come closer than ``link`` (:func:`clusters`; a cloud sparser
  than ``link`` splits an obstacle's faces into fragments inside its box, and
  they merge again). Obstacles closer than ``link`` merge into one cluster and
  the gap between them is closed (a moving obstacle never merges with a static
  one);
* each cluster's polytope (:func:`fit_polytope`): the axis-aligned box of its
  points, cut by the planes of its convex hull's largest faces (coplanar hull
  triangles merged; at most ``MAX_PLANES`` besides the box's six) that hold a
  point inside the box (a plane through points on the box's faces only cuts a
  corner off the box where the samples stop short of it). Every plane
  supports the points (all lie on its inner side), so the polytope contains
  their hull; fewer planes make it larger, never smaller. An axis-aligned box
  sampled on its faces (at least one point on each) *is* its points' bounding
  box, holes and edges included, and a rotated one is closed by its face
  planes (with at least three points on each face). Where the samples stop
  short of a corner that neither the bounding box nor a kept plane reaches (a
  rotated box's corners; a curved surface between samples, whose hull faces
  are chords) the model is smaller than the obstacle by that much;
* a static cluster that is not convex is left out (:func:`hull_depth`: a point
  lies deeper than ``CONVEX_TOLERANCE`` inside the hull of its cluster; points
  sampled on a convex surface all lie on their hull's boundary). Its polytope
  would close the world's concavities (a wall's port, a ring's hole, a gap
  between two obstacles closer than ``link``), so such a cluster is left to
  the cloud. A moving group's clusters are closed whole: at the first
  observation every point counts as moving, and an obstacle that chains to a
  passing one is modelled with it until their motions tell them apart;
* a cluster whose points lie on a sphere (:func:`fit_sphere`: all within
  ``SPHERE_TOLERANCE`` of their least-squares sphere; the paper's
  moving spheres) is that sphere's ball, its radius grown to hold every point,
  instead of a polytope. It is the sphere, where the points' bounding box sticks
  out by up to 0.73 radii at its corners and their hull's faces, chords, cut
  under it by up to the depth of the largest cap between samples (about 0.1 m
  for 30 points on a 0.5 m sphere). Like the polytope, it holds the points' hull.
  A moving cluster on no one sphere is halved at its median along its longest
  side (up to ``SPLIT_DEPTH`` times, :func:`sphere_parts`); where every part lies
  on a sphere (balls touching in a row chain into one cluster) the parts are
  balls, else the cluster is one polytope.

Distance to a polytope (:func:`polytope_distance`): the larger of the signed
distance to its box (exact) and of ``n_k . x - b_k`` over its planes; at most
the Euclidean distance outside (a lower bound: safe; exact for a box), and minus
the depth inside. The robot's clearance to the polytopes
(:func:`robot_clearance`) uses ``COVER_SPHERES`` balls per link whose union
contains the link body (``ncedf.shapes.sphere_cover_radius``): ``min (d(c) - R)``
over the balls is at most the clearance of the body. Distance to a
sphere's ball: ``||x - c|| - R``, exact.

A moving cluster's polytope translates at the mean velocity of its points
(the caller's estimate, e.g. from successive clouds), so a rollout state ``t``
seconds ahead is scored against the polytope moved by ``t`` times it.

Fixed sizes for the jitted controller: :class:`Polytopes` holds
``MAX_CLUSTERS`` clusters of ``MAX_PLANES`` planes; unused ones are masked. The
largest clusters (by point count) are kept when there are more.
"""

from __future__ import annotations

import functools
import itertools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import ConvexHull, QhullError, cKDTree

from ncedf.robot import RobotSpec
from ncedf.shapes import SphereShape

#: The directions of the support planes that cut a convex part's box corners (:func:`corner_planes`):
#: the diagonals of the coordinate planes.
DIAGONALS = np.array([v for v in itertools.product((-1.0, 0.0, 1.0), repeat=3) if sum(map(abs, v)) == 2]) / np.sqrt(2.0)
#: The planes a convex part's polytope holds at most with its corner planes (at most ``MAX_PLANES``).
CORNER_PLANES = 4
#: A corner plane's depth times its edge's length, in square gaps, where the samples show the edge
#: empty (:func:`corner_planes`): pi / sqrt(2).
CORNER_EVIDENCE = np.pi / np.sqrt(2.0)
#: Clusters a :class:`Polytopes` holds (the largest are kept).
MAX_CLUSTERS = 8
#: Hull planes per polytope (besides its bounding box's six).
MAX_PLANES = 8
#: Hull planes whose merged area is below this share of the hull's area are left out.
MIN_PLANE_SHARE = 0.05
#: Hull triangles whose unit normals and offsets agree to this (1, m) are one plane.
PLANE_TOLERANCE = 1e-3
#: Plane counts a polytope's distance is compiled for (its valid planes rounded up to one of them).
PLANE_BUCKETS = (0, 2, 4, MAX_PLANES)
#: A cluster with a point deeper than this inside its hull is not convex and is left out, m.
CONVEX_TOLERANCE = 0.01
#: A cluster whose points all lie within this of their least-squares sphere is that sphere, m.
SPHERE_TOLERANCE = 0.01
#: The fewest points that tell a sphere (any four lie on one).
SPHERE_MIN_POINTS = 5
#: Halvings of a moving cluster that is not on one sphere, in search of parts that each are.
SPLIT_DEPTH = 2
#: Groups of points whose clusters' fit :func:`fit_polytopes` keeps (a static group repeats every step).
FIT_CACHE = 8
#: Balls per link that cover the robot body for the clearance to the polytopes.
COVER_SPHERES = 10
#: Robot states per pass of :func:`robot_clearance`.
CLEARANCE_CHUNK = 8192


class Polytopes(NamedTuple):
    """Convex polytopes: a box ``lower <= x <= upper`` cut by the half-spaces
    ``n_k . x <= b_k`` of its valid planes, or the ball
    ``||x - centre|| <= radius`` (a pytree; :func:`fit_polytopes` gives numpy arrays).

    lower, upper: (C, 3) m.  normals: (C, K, 3) outward unit normals.  offsets: (C, K) m.
    valid: (C, K) bool.  present: (C,) bool; an absent cluster is no obstacle.
    velocity: (C, 3) m/s, the polytope's translation (the mean velocity of its points).
    centre: (C, 3) m, radius: (C,) m, ball: (C,) bool: the cluster lies on that sphere and is its ball.
    left_out: (scalar int) the static clusters left out as not convex: obstacles the model misses.
    mount: None, or (C,) bool: wholly under the robot's base plane, so no obstacle to its first link
    (``ncedf.mount``).
    """

    lower: jnp.ndarray
    upper: jnp.ndarray
    normals: jnp.ndarray
    offsets: jnp.ndarray
    valid: jnp.ndarray
    present: jnp.ndarray
    velocity: jnp.ndarray
    centre: jnp.ndarray
    radius: jnp.ndarray
    ball: jnp.ndarray
    left_out: jnp.ndarray
    mount: jnp.ndarray | None = None


def for_first_link(polytopes: Polytopes) -> Polytopes:
    """The polytopes the first link is scored against: those marked as under its base plane left out."""
    return polytopes._replace(present=polytopes.present & ~polytopes.mount, mount=None)


def per_link(score, model, first, centres: jnp.ndarray) -> jnp.ndarray:
    """``score(model, centres)`` for cover-ball centres (..., M, n, 3), (..., M, n) m, with the first
    link's balls scored against ``first`` instead where it is not None (the model less what lies
    under the base plane, ``ncedf.mount``): each ball scored once."""
    if first is None:
        return score(model, centres)
    return jnp.concatenate([score(first, centres[..., :1, :, :]), score(model, centres[..., 1:, :, :])], axis=-2)


def static_rows(points: np.ndarray, mask: np.ndarray, previous: np.ndarray, previous_mask: np.ndarray) -> np.ndarray:
    """(P,) bool: real rows equal to the same row of the previous cloud (all (P, 3) / (P,))."""
    return mask & previous_mask & np.all(points == previous, axis=-1)


def observed_motion(points: np.ndarray, mask: np.ndarray, previous: np.ndarray, previous_mask: np.ndarray,
                    dt: float) -> tuple[np.ndarray, np.ndarray]:
    """The rows of the padded cloud (P, 3) with mask (P,) that stood still since the previous one
    (P, 3), (P,) dt seconds earlier (:func:`static_rows`), and each row's velocity (P, 3) m/s: its
    displacement over dt, zero where either cloud has padding (the scenarios observe row ``i`` as the
    same physical point every step)."""
    points, mask = np.asarray(points), np.asarray(mask)
    previous, previous_mask = np.asarray(previous), np.asarray(previous_mask)
    both = (mask & previous_mask)[:, None]
    velocity = np.where(both, (points - previous) / np.float32(dt), np.float32(0.0)).astype(np.float32)
    return static_rows(points, mask, previous, previous_mask), velocity


def _components(n: int, pairs: np.ndarray) -> np.ndarray:
    """(n,) int label of each of n nodes: the connected components of the edges ``pairs`` (E, 2)."""
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    return connected_components(graph, directed=False)[1]


def clusters(points: np.ndarray, link: float, groups: np.ndarray | None = None, bounds: bool = True) -> np.ndarray:
    """(P,) int cluster label of each point (P, 3), within each group (``groups`` (P,) labels;
    None = one group): single linkage at distance ``link``, m, then (``bounds``) clusters whose
    bounding boxes lie within ``link`` of each other merged, until none do.

    The merge keeps a sparsely sampled obstacle whole: where the gaps between its samples
    exceed ``link`` single linkage splits its faces into fragments, each inside the obstacle's
    bounding box, and fragments whose boxes lie within ``link`` merge, while obstacles whose
    bounding boxes lie further apart than that stay apart. A gap wider than ``link`` that no
    sample spans stays open.
    """
    n = len(points)
    if n == 0:
        return np.zeros(0, int)
    groups = np.zeros(n, int) if groups is None else np.asarray(groups)
    pairs = cKDTree(points).query_pairs(link, output_type="ndarray")
    labels = _components(n, pairs[groups[pairs[:, 0]] == groups[pairs[:, 1]]])
    while bounds:
        count = labels.max() + 1
        lower = np.full((count, 3), np.inf)
        upper = np.full((count, 3), -np.inf)
        np.minimum.at(lower, labels, points)
        np.maximum.at(upper, labels, points)
        group = np.zeros(count, groups.dtype)
        group[labels] = groups
        gap = np.maximum(0.0, np.maximum(lower[:, None] - upper[None], lower[None] - upper[:, None]))
        near = (np.linalg.norm(gap, axis=-1) <= link) & (group[:, None] == group[None])
        merged = _components(count, np.argwhere(near))
        if merged.max() + 1 == count:
            break
        labels = merged[labels]
    return labels


def convex_hull(points: np.ndarray):
    """The convex hull of the points (P, 3), or None where they span no volume (fewer than 4, or
    all on a plane or line)."""
    try:
        return ConvexHull(np.asarray(points, np.float64))
    except (QhullError, ValueError):
        return None


def triangle_areas(corners: np.ndarray) -> np.ndarray:
    """(F,) the areas of the triangles of corners (F, 3, 3), m^2."""
    return 0.5 * np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=-1)


def _hull_planes(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Merged hull planes (normals (Q, 3), offsets (Q,), areas (Q,)), largest first; none if degenerate."""
    hull = convex_hull(points)
    if hull is None:
        return np.zeros((0, 3)), np.zeros(0), np.zeros(0)
    normals, offsets = hull.equations[:, :3], -hull.equations[:, 3]
    areas = triangle_areas(points[hull.simplices])
    keys = np.round(np.concatenate([normals, offsets[:, None]], axis=1) / PLANE_TOLERANCE).astype(np.int64)
    _, group = np.unique(keys, axis=0, return_inverse=True)
    group = group.reshape(-1)
    merged = np.bincount(group, weights=areas)
    first = np.full(len(merged), -1)
    order = np.argsort(-areas, kind="stable")
    first[group[order[::-1]]] = order[::-1]  # the largest triangle of each group wins
    rank = np.argsort(-merged, kind="stable")
    return normals[first[rank]], offsets[first[rank]], merged[rank]


def fit_sphere(points: np.ndarray) -> tuple[np.ndarray, float] | None:
    """The sphere that the points (P, 3) of one cluster lie on: the centre (3,) of their
    least-squares sphere (``|p|^2 = 2 c . p + k``) and the radius that holds every point, m;
    None unless there are at least five points, every point is within ``SPHERE_TOLERANCE``
    of that sphere and its ball is smaller than the points' bounding box (which rules out
    near-planar points)."""
    points = np.asarray(points, np.float64)
    if len(points) < SPHERE_MIN_POINTS:
        return None
    design = np.concatenate([2.0 * points, np.ones((len(points), 1))], axis=1)
    solution, _, rank, _ = np.linalg.lstsq(design, np.sum(points**2, axis=1), rcond=None)
    if rank < 4:  # all on a plane
        return None
    centre = solution[:3]
    reach = np.sqrt(np.sum((points - centre) ** 2, axis=1))
    radius = float(reach.max())
    ball = 4.0 / 3.0 * np.pi * radius**3
    if radius - reach.min() > SPHERE_TOLERANCE or ball >= np.prod(points.max(axis=0) - points.min(axis=0)):
        return None
    return centre, radius


def fit_polytope(points: np.ndarray, planes: bool = True) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The polytope of one cluster (module docstring): its bounding box lower, upper (3,) and
    hull planes normals (K, 3), offsets (K,), K <= MAX_PLANES (the box's own planes left out;
    none with ``planes`` False)."""
    points = np.asarray(points, np.float64)
    lower, upper = points.min(axis=0), points.max(axis=0)
    if not planes:
        return lower, upper, np.zeros((0, 3)), np.zeros(0)
    hull_n, hull_b, areas = _hull_planes(points)
    on_box = np.any(np.abs(points[:, None] - np.stack([lower, upper])) < PLANE_TOLERANCE, axis=(1, 2))  # (P,)
    on_plane = np.abs(points @ hull_n.T - hull_b) < PLANE_TOLERANCE  # (P, Q)
    inner = np.any(on_plane & ~on_box[:, None], axis=0)  # (Q,) the plane holds a point inside the box
    keep = (areas >= MIN_PLANE_SHARE * areas.sum()) & inner
    return lower, upper, hull_n[keep][:MAX_PLANES], hull_b[keep][:MAX_PLANES]


def hull_depth(points: np.ndarray) -> float:
    """How deep the deepest of the points (P, 3) lies inside their convex hull, m: the least
    distance to a hull face's plane (0 where every point is on the hull's boundary, and where
    the points span no volume)."""
    hull = convex_hull(points)
    if hull is None:
        return 0.0
    depth = -(points @ hull.equations[:, :3].T + hull.equations[:, 3])  # (P, F) >= 0 up to rounding
    return float(max(np.max(np.min(depth, axis=1)), 0.0))


@functools.lru_cache(maxsize=FIT_CACHE)
def _fit_group(data: bytes, link: float, bounds: bool) -> tuple[tuple, ...]:
    """The clusters of one group's points, given as the bytes of an (S, 3) float64 array
    (:func:`clusters` with ``bounds``): per cluster (its members' indices, then
    :func:`fit_polytope`'s four arrays and :func:`fit_sphere`'s result; a sphere's polytope
    without hull planes, as its ball replaces it). Cached: a static group repeats from step
    to step. With ``bounds`` (the static group) a cluster that is not convex (:func:`hull_depth`) is
    left out: its fit is None."""
    points = np.frombuffer(data, np.float64).reshape(-1, 3)
    labels = clusters(points, link, bounds=bounds)
    fits = []
    for label in range(labels.max(initial=-1) + 1):
        members = np.flatnonzero(labels == label)
        sphere = fit_sphere(points[members])
        if bounds and sphere is None and hull_depth(points[members]) > CONVEX_TOLERANCE:
            fits.append((members, None))
            continue
        parts = None if bounds or sphere is not None else sphere_parts(points[members], SPLIT_DEPTH)
        for part, ball in parts or [(np.arange(len(members)), sphere)]:
            fits.append((members[part], *fit_polytope(points[members[part]], planes=ball is None), ball))
    return tuple(fits)


def sphere_parts(points: np.ndarray, depth: int) -> list[tuple[np.ndarray, tuple]] | None:
    """The parts of points (P, 3) that each lie on a sphere (:func:`fit_sphere`): the indices of each
    part's points and its sphere, halved at the median along the bounding box's longest side up to
    ``depth`` times; None unless every part lies on one (balls touching in a row, one moving cluster)."""
    sphere = fit_sphere(points)
    if sphere is not None:
        return [(np.arange(len(points)), sphere)]
    if depth == 0 or len(points) < 2 * SPHERE_MIN_POINTS:  # halves too small to tell a sphere
        return None
    order = np.argsort(points[:, np.argmax(np.ptp(points, axis=0))], kind="stable")
    out = []
    for half in (order[: len(points) // 2], order[len(points) // 2:]):
        parts = sphere_parts(points[half], depth - 1)
        if parts is None:
            return None
        out += [(half[part], ball) for part, ball in parts]
    return out


def fit_polytopes(points: np.ndarray, link: float, groups: np.ndarray | None = None,
                  velocity: np.ndarray | None = None, bounds: tuple | None = None) -> Polytopes:
    """Polytopes of the clusters of ``points`` (S, 3) at single-linkage distance ``link`` (m),
    within each group (``groups`` (S,) labels, e.g. static or moving; None = one group).

    bounds: the group labels whose clusters also merge by their bounding boxes (:func:`clusters`);
    None = every group's.

    velocity: (S, 3) m/s of the points (None = at rest); a polytope moves at the mean of its
    points'. The MAX_CLUSTERS largest clusters are kept; padded and masked to the fixed capacity.
    A cluster on a sphere (:func:`fit_sphere`) is that sphere's ball instead. A group's fit is
    cached by its points (the last ``FIT_CACHE`` groups), so a static group is fitted once.
    """
    points = np.ascontiguousarray(points, np.float64)
    groups = np.zeros(len(points), int) if groups is None else np.asarray(groups)
    found, left_out = [], 0  # (members' indices into points, fit); clusters left out
    for group in np.unique(groups):
        index = np.flatnonzero(groups == group)
        fits = _fit_group(points[index].tobytes(), float(link), bounds is None or group in bounds)
        kept = [fit for fit in fits if fit[1] is not None]
        left_out += len(fits) - len(kept)
        found += [(index[members], fit) for members, *fit in kept]
    found.sort(key=lambda cluster: -len(cluster[0]))  # stable: the largest first
    return pack(found, velocity, left_out)


def fit_part(points: np.ndarray, gap: float) -> tuple:
    """One convex obstacle's points (P, 3), sampled with holes of radius ``gap`` m, closed whole,
    without clustering: :func:`fit_polytope`'s four arrays, its free plane slots up to
    ``CORNER_PLANES`` filled by :func:`corner_planes`, and :func:`fit_sphere`'s result (a sphere's
    polytope without planes)."""
    sphere = fit_sphere(points)
    lower, upper, normals, offsets = fit_polytope(points, planes=sphere is None)
    if sphere is None:
        normals, offsets = corner_planes(points, lower, upper, normals, offsets, gap)
    return lower, upper, normals, offsets, sphere


def corner_planes(points: np.ndarray, lower: np.ndarray, upper: np.ndarray, normals: np.ndarray,
                  offsets: np.ndarray, gap: float) -> tuple[np.ndarray, np.ndarray]:
    """The planes (K, 3), (K,) with support planes of the points (P, 3) along the ``DIAGONALS`` added
    up to ``CORNER_PLANES`` in all, those that cut deepest into the box [lower, upper] first, where
    the samples show the box's edge empty: cut d deep along an edge of length L, a box's two faces
    would hold strips of width ``sqrt(2) d`` along it without a sample, ``2 sqrt(2) d L`` m^2, empty
    with probability at most ``n^-2`` at the cloud's ``gap`` (``ncedf.parts``: ``pi rho gap^2 =
    ln n``) where ``d L >= CORNER_EVIDENCE gap^2``. A pillar's box (8 m edges) is cut at its four
    vertical edges (0.41 radii deep); a box whose samples stop a few cm short of its edges is not.
    Each plane holds every point, so the polytope still holds their hull."""
    support = points @ DIAGONALS.T  # (P, D)
    box = np.maximum(DIAGONALS * lower, DIAGONALS * upper).sum(axis=1)  # (D,) the box's support
    depth = box - support.max(axis=0)
    length = (DIAGONALS == 0) @ (upper - lower)  # (D,) the edge's length: the box along the direction's zero axis
    depth = np.where(depth * length >= CORNER_EVIDENCE * gap**2, depth, 0.0)
    order = [d for d in np.argsort(-depth, kind="stable") if depth[d] > PLANE_TOLERANCE]
    extra = order[:max(CORNER_PLANES - len(offsets), 0)]
    return (np.concatenate([normals, DIAGONALS[extra]]), np.concatenate([offsets, support.max(axis=0)[extra]]))


def pack(found: list[tuple], velocity: np.ndarray | None = None, left_out: int = 0) -> Polytopes:
    """The :class:`Polytopes` of the first ``MAX_CLUSTERS`` of ``found``: (members' indices, fit) per
    cluster, the fit as :func:`fit_part` gives it; each moves at the mean ``velocity`` (S, 3) m/s of its
    members (None: at rest)."""
    lower = np.zeros((MAX_CLUSTERS, 3), np.float32)
    upper = np.zeros((MAX_CLUSTERS, 3), np.float32)
    normals = np.zeros((MAX_CLUSTERS, MAX_PLANES, 3), np.float32)
    offsets = np.zeros((MAX_CLUSTERS, MAX_PLANES), np.float32)
    valid = np.zeros((MAX_CLUSTERS, MAX_PLANES), bool)
    present = np.zeros(MAX_CLUSTERS, bool)
    moving = np.zeros((MAX_CLUSTERS, 3), np.float32)
    centre = np.zeros((MAX_CLUSTERS, 3), np.float32)
    radius = np.zeros(MAX_CLUSTERS, np.float32)
    ball = np.zeros(MAX_CLUSTERS, bool)
    for c, (members, (box_lower, box_upper, n, b, sphere)) in enumerate(found[:MAX_CLUSTERS]):
        lower[c], upper[c] = box_lower, box_upper
        normals[c, : len(b)], offsets[c, : len(b)], valid[c, : len(b)] = n, b, True
        present[c] = True
        if sphere is not None:
            centre[c], radius[c] = sphere
            ball[c] = True
        if velocity is not None:
            moving[c] = velocity[members].mean(axis=0)
    return Polytopes(lower, upper, normals, offsets, valid, present, moving, centre, radius, ball,
                     np.int32(left_out))


def _root(square: jnp.ndarray) -> jnp.ndarray:
    """The square root of a sum of squares >= 0, with a zero derivative where it is 0 (a point inside
    a box, outside none of its faces) instead of sqrt's NaN, so that a gradient through the distance
    (``ncedf.obstacle_model.soft_clearance``) stays finite; the values are sqrt's."""
    positive = square > 0
    return jnp.where(positive, jnp.sqrt(jnp.where(positive, square, 1.0)), 0.0)


@functools.partial(jax.jit, static_argnames=("dense", "turning"))
def polytope_distance(x: jnp.ndarray, polytopes: Polytopes, t=0.0, dense: bool | None = None,
                      turning: bool = False) -> jnp.ndarray:
    """(...,) lower bound of the distance from points x (..., 3) to the nearest polytope,
    each moved by ``t`` times its velocity (t: s, broadcastable with x[..., 0]), m; negative
    inside (minus the depth); +inf without polytopes.

    ``turning``: each polytope anywhere within its speed times t of where it is (an obstacle
    that may turn or stop at any instant, no faster than seen): its distance unmoved less
    ``|v| t``. Proof: every such position lies in P + B(|v| t), whose distance is ``d_P - |v| t``
    outside it (P convex) and negative inside, and d_P's lower bound less ``|v| t`` bounds it.

    Per polytope: the larger of the signed distance to its box (exact) and of the
    planes' ``n_k . x - b_k``; a lower bound because the polytope lies in each. Per
    sphere: the signed distance to its ball (exact).
    Written per component and unrolled over the planes, so every operation is
    elementwise over the points and XLA fuses a cluster into one loop; the clusters
    are a ``lax.fori_loop`` (the program holds one cluster's code, not ``MAX_CLUSTERS``
    copies: compile time), and a cluster runs only what it has (``lax.switch``: absent,
    its ball, or its box and its plane slots up to the last valid one, rounded up to
    ``PLANE_BUCKETS``), since the arithmetic of the capacity is the cost (the
    paper's boxes and spheres fill 4 or 5 of the ``MAX_CLUSTERS`` slots: its boxes without
    planes, its spheres as balls). That is the CPU's form; other devices compute
    every cluster and plane slot at once, with no loop or branch (a GPU runs a
    loop's steps and branches one after another). ``dense`` chooses the form:
    None for the device's (``jax.lax.platform_dependent``), True for all at once,
    False for the loop; the two agree to float rounding. Jitted: host code calls it on numpy
    arrays (the grid model's fit), and each eager call would trace and compile the loop again.
    """
    looped = functools.partial(_looped_distance, turning=turning)
    as_dense = functools.partial(_dense_distance, turning=turning)
    if dense is None:
        return jax.lax.platform_dependent(x, polytopes, t, cpu=looped, default=as_dense)
    return (as_dense if dense else looped)(x, polytopes, t)


def _looped_distance(x: jnp.ndarray, polytopes: Polytopes, t=0.0, turning: bool = False) -> jnp.ndarray:
    """:func:`polytope_distance`, a loop over the clusters that skips what a cluster lacks."""
    p = jax.tree.map(jnp.asarray, polytopes)  # indexed by the loop's cluster index
    t = jnp.asarray(t, x.dtype)
    xs = [x[..., i] for i in range(3)]

    def moved(c):  # the points relative to cluster c's motion (turning: where it is)
        return xs if turning else [xs[i] - t * p.velocity[c, i] for i in range(3)]

    def spread(c, d):  # turning: less the distance cluster c may cover
        return d - t * jnp.linalg.norm(p.velocity[c]) if turning else d

    def ball(c, nearest):  # cluster c's ball
        r = moved(c)
        return jnp.minimum(nearest, spread(c, jnp.sqrt(sum((r[i] - p.centre[c, i]) ** 2 for i in range(3)))
                                              - p.radius[c]))

    def cluster(planes, c, nearest):  # box c cut by its first ``planes`` plane slots
        rel = moved(c)
        centre, half = 0.5 * (p.upper[c] + p.lower[c]), 0.5 * (p.upper[c] - p.lower[c])
        q = [jnp.abs(rel[i] - centre[i]) - half[i] for i in range(3)]
        outside = _root(sum(jnp.maximum(qi, 0.0) ** 2 for qi in q))
        d = outside + jnp.minimum(jnp.maximum(jnp.maximum(q[0], q[1]), q[2]), 0.0)
        for k in range(planes):
            s = sum(rel[i] * p.normals[c, k, i] for i in range(3)) - p.offsets[c, k]
            d = jnp.maximum(d, jnp.where(p.valid[c, k], s, -jnp.inf))
        return jnp.minimum(nearest, spread(c, d))

    slots = p.valid.shape[1]
    buckets = tuple(sorted({min(b, slots) for b in PLANE_BUCKETS} | {slots}))
    used = jnp.max(jnp.where(p.valid, jnp.arange(1, slots + 1), 0), axis=-1, initial=0)  # (C,) up to the last valid
    kinds = jnp.where(p.present, jnp.where(p.ball, 1, 2 + jnp.searchsorted(jnp.asarray(buckets), used)), 0)
    branches = [lambda c, n: n, ball] + [functools.partial(cluster, b) for b in buckets]
    nearest = jnp.full(jnp.broadcast_shapes(xs[0].shape, t.shape), jnp.inf, x.dtype)
    return jax.lax.fori_loop(0, p.present.shape[0], lambda c, n: jax.lax.switch(kinds[c], branches, c, n), nearest)


def _dense_distance(x: jnp.ndarray, polytopes: Polytopes, t=0.0, turning: bool = False) -> jnp.ndarray:
    """:func:`polytope_distance`, every cluster and plane slot at once (a trailing axis C),
    elementwise per component and unrolled over the plane slots as in the loop, so XLA fuses it."""
    p = jax.tree.map(jnp.asarray, polytopes)
    t = jnp.asarray(t, x.dtype)[..., None]
    rel = [x[..., None, i] - (0.0 if turning else t * p.velocity[:, i]) for i in range(3)]  # 3 x (..., C)
    q = [jnp.abs(rel[i] - 0.5 * (p.upper[:, i] + p.lower[:, i])) - 0.5 * (p.upper[:, i] - p.lower[:, i])
         for i in range(3)]
    d = (_root(sum(jnp.maximum(qi, 0.0) ** 2 for qi in q))
         + jnp.minimum(jnp.maximum(jnp.maximum(q[0], q[1]), q[2]), 0.0))
    for k in range(p.valid.shape[1]):
        s = sum(rel[i] * p.normals[:, k, i] for i in range(3)) - p.offsets[:, k]
        d = jnp.maximum(d, jnp.where(p.valid[:, k], s, -jnp.inf))
    ball = jnp.sqrt(sum((rel[i] - p.centre[:, i]) ** 2 for i in range(3))) - p.radius
    d = jnp.where(p.ball, ball, d)
    if turning:
        d = d - t * jnp.linalg.norm(p.velocity, axis=-1)
    return jnp.min(jnp.where(p.present, d, jnp.inf), axis=-1, initial=jnp.inf)


def robot_clearance(arcs: jnp.ndarray, frames: jnp.ndarray, spec: RobotSpec, polytopes: Polytopes,
                    t=0.0, dense: bool | None = None, turning: bool = False) -> jnp.ndarray:
    """(B...,) lower bound of the robot body's clearance to the polytopes, each moved by
    ``t`` times its velocity (t: s; B... is the broadcast of the batch shapes of arcs and t), m
    (``turning``: anywhere within its speed times t, :func:`polytope_distance`).

    On the CPU the states are scored ``CLEARANCE_CHUNK`` at a time (``jax.lax.map``), so
    that the cover centres and their distances of one pass stay in its caches, by the
    loop of :func:`polytope_distance`; other devices score them all at once, by its dense
    form. ``dense`` chooses as there.

    Args:
      arcs: (B..., M, 3) arc lengths, m.  frames: (B..., M + 1, 4, 4) their forward kinematics.
    """
    cover = SphereShape(spec, per_link=COVER_SPHERES)

    def scored(as_dense, states):  # configurations (S, M, 3), (S, M + 1, 4, 4), (S,) -> (S,)
        arc, frame, time = states
        geom = cover.prepare(arc, frame)  # centres (S, M, n, 3), radius (S, M)
        first = None if polytopes.mount is None else for_first_link(polytopes)
        d = per_link(lambda model, x: polytope_distance(x, model, time[:, None, None], as_dense, turning),
                     polytopes, first, geom.centres)
        return jnp.min(d - geom.radius[..., None], axis=(-2, -1))

    def chunked(states):  # whole chunks in a loop, then the rest
        n = states[0].shape[0]
        whole = n - n % CLEARANCE_CHUNK
        parts = []
        if whole:
            chunks = jax.tree.map(lambda x: x[:whole].reshape((-1, CLEARANCE_CHUNK) + x.shape[1:]), states)
            parts.append(jax.lax.map(functools.partial(scored, False), chunks).reshape(-1))
        if n > whole:
            parts.append(scored(False, jax.tree.map(lambda x: x[whole:], states)))
        return jnp.concatenate(parts)

    t = jnp.asarray(t, arcs.dtype)
    batch = jnp.broadcast_shapes(arcs.shape[:-2], t.shape)
    states = tuple(jnp.broadcast_to(x, batch + x.shape[x.ndim - core:]).reshape((-1,) + x.shape[x.ndim - core:])
                   for x, core in ((arcs, 2), (frames, 3), (t, 0)))
    at_once = functools.partial(scored, True)
    if dense is None:
        return jax.lax.platform_dependent(states, cpu=chunked, default=at_once).reshape(batch)
    return (at_once if dense else chunked)(states).reshape(batch)
