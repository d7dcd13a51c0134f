"""The grid model: the static cloud's surfaces closed on a voxel grid, and their distance field.

The convex model (``ncedf.obstacle_model``) closes a sparsely sampled surface by
its cluster's hull, which closes a wall's window too. The grid model closes it
without assuming convexity. First the static points are cut into parts at empty
slabs that one obstacle's samples would not leave (``ncedf.parts``); the
``MAX_CLUSTERS`` largest convex parts are closed as their polytopes
(``ncedf.convex.fit_part``: exact for a box, within a chord for a pillar, where
the grid's closing moves every edge out), unless together they shut the goal in
(then every part goes to the grid); the other points are closed on the grid:

* cells: a grid of spacing ``h`` over the static points, the goal and the robot's
  base (the world origin), grown by ``pad``; ``h`` is ``resolution``, coarsened
  where the box would hold more than ``max_cells``. Every grid's values are
  padded to ``max_cells`` (:class:`Grid`), so one compiled program serves grids
  of every box (a new shape would compile the controller's step again);
* closed cells: the cells that hold a point, grown by a radius ``reach`` and
  shrunk again by ``sqrt(reach^2 - gap^2)`` (every cell within ``reach`` of a
  hit cell, less those within the shrink of a cell that is not). Over a hole of
  radius ``gap`` in a sampled surface the grown balls still stand
  ``sqrt(reach^2 - gap^2)`` high, so the hole stays closed, while an opening's
  edges move in by only ``reach - sqrt(reach^2 - gap^2)`` (a cavity or passage
  narrower than ``2 reach`` fills, though). A cell is closed only where the
  closings at two reaches, ``reach`` and ``INNER reach``, both close it: each
  closes the holes; the larger moves an opening's edges less, the smaller fills
  only openings narrower than ``2 INNER reach``. Each surface is closed on its own:
  the hit cells joined wherever two lie within ``LINK`` gaps, so that a passage
  between two obstacles wider than that (a lane between pillars, a slot between
  slabs) keeps its width less the two edges' move. A surface sampled at density
  rho splits at a link r about as often as one of its n samples has no other
  within r: ``n exp(-pi rho r^2)``, and half the exponent for a sample on the
  surface's edge; at the gap (``pi rho gap^2 = ln n``) ``n^(1 - LINK^2)``, and
  ``n^(-LINK^2 / 2)`` per edge sample (for a thousand samples 1e-6 and 3e-5). Free cells that do not
  connect to the grid's border are enclosed by the closed surfaces, inside a
  solid, and are closed too;
* the field: at a free cell's centre the distance to the nearest observed point
  or closed cell without a point, whichever is nearer (the points' distance
  exact, by a k-d tree, within ``EXACT_BAND`` of them; farther, the distance to
  the hit cells' centres less half a cell's diagonal); inside the closed cells
  minus the distance to the nearest free cell.

Distance of a point x (:func:`grid_distance`): with q the point of the grid's box
nearest to x (x itself inside it) and c the cell nearest to q, ``b = f(c) - |q - c|``
inside the box and ``sqrt(|x - q|^2 + max(b, 0)^2)`` outside it. Proof that it is at
most the distance d(x) from x to the observed points and the closed cells' centres:
at a free c, ``f(c)`` is at most the distance from c to them (a point p lies within
``h sqrt(3) / 2`` of its cell's centre, so the hit cells' distance less that is at
most |c - p|), and that distance is 1-Lipschitz, so b <= d(q); at a closed c, b is
negative. Outside the box, every observed point and cell centre o lies in the box,
a convex set of which q is the projection of x, so ``(x - q) . (o - q) <= 0`` and ``|x - o|^2 >= |x - q|^2 +
|q - o|^2 >= |x - q|^2 + max(b, 0)^2``. (Bounding outside by ``f(c) - |x - c|`` alone
made a link above a low obstacle's grid look deep inside it.) The robot's clearance
(:func:`fit_clearance`) is that at the centres of the balls that cover each link
(``ncedf.convex.COVER_SPHERES``), less their radii.

The rows of the cloud seen to move (observed in both of two successive clouds, at
different places) are not in the grid: they are closed into their clusters'
polytopes or balls as by the convex model (``ncedf.convex``, single linkage at
``link``, a moving cluster closed whole), each moved at its points' mean velocity.
Left to the points, a link could pass between the samples of a moving ball.

The fit runs in numpy and scipy outside the jitted step, once per static cloud
and goal (cached), like the convex model's.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from scipy import ndimage
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from ncedf.compile_cache import bucket
from ncedf.convex import (COVER_SPHERES, MAX_CLUSTERS, Polytopes, fit_part, fit_polytopes, for_first_link,
                          observed_motion, pack, per_link, polytope_distance)
from ncedf.parts import is_convex, split
from ncedf.robot import BASE, RobotSpec
from ncedf.shapes import SphereShape
from ncedf.validate import check_fields

#: Static clouds (with their goals) whose grids are kept.
GRID_CACHE = 4
#: The field's value without static obstacles, m (finite: the interpolation weighs it by zero).
FAR = 1e6
#: The reach at first, in gaps.
REACH = 2.0
#: The second closing's reach, a fraction of the first (module docstring).
INNER = 0.75
#: The distance that joins two hit cells into one surface, in gaps (module docstring).
LINK = 1.75
#: The factor the reach shrinks by while it shuts the goal in.
SHRINK = 0.9
#: Free cells within this distance of a hit cell get the points' exact distance, m (beyond it the
#: field's error is small beside the distance).
EXACT_BAND = 1.0


class Grid(NamedTuple):
    """A field on a grid (a pytree): at the cell centres ``origin + h * index``, m, the values of
    ``shape`` (3,) int cells (X, Y, Z), flattened (C-order) and padded to a fixed length C >= X Y Z
    (``values`` (C,)), so that grids of other shapes share one compiled program; ``spacing`` h, m
    (a scalar array)."""

    origin: jnp.ndarray
    spacing: jnp.ndarray
    values: jnp.ndarray
    shape: jnp.ndarray

    def array(self) -> np.ndarray:
        """(X, Y, Z) the values on the host."""
        shape = tuple(int(n) for n in np.asarray(self.shape))
        return np.asarray(self.values)[: int(np.prod(shape))].reshape(shape)


def padded(origin: np.ndarray, h: float, field: np.ndarray, length: int) -> Grid:
    """The :class:`Grid` of the field (X, Y, Z) at ``origin`` (3,) with spacing h, its values padded to
    ``length`` (at least X Y Z), on the device."""
    values = np.full(max(length, field.size), FAR, np.float32)
    values[: field.size] = field.ravel()
    return Grid(jnp.asarray(origin, jnp.float32), jnp.float32(h), jnp.asarray(values),
                jnp.asarray(field.shape, jnp.int32))


class GridFit(NamedTuple):
    """The grid model's fit (a pytree): the still points' convex ``parts`` as polytopes and the
    ``grid`` of the others, and the ``moving`` clusters' polytopes (none present before a row is
    seen to move)."""

    grid: Grid
    parts: Polytopes
    moving: Polytopes


@dataclasses.dataclass(frozen=True)
class GridModel:
    """The grid model (module docstring): holes of radius ``gap`` m closed, cells of
    ``resolution`` m (at most ``max_cells``) over the cloud, goal and base grown by ``pad`` m.

    The reach starts at ``REACH * gap``; where that shuts the goal in (no cell with a field of
    at least ``keep_open`` m leads from the goal's cell to the grid's border) it shrinks by
    ``SHRINK`` until one does, down to a cell (below ``gap`` the cells are grown only, and the
    widest holes stay): the passage to the goal is narrower than the reach fills.

    A pose goal says that the end effector arrives along its approach axis (its z axis), so the
    way in behind it is free: the cells within ``corridor_radius`` m of the segment
    ``corridor_length`` m back from the goal along the axis are kept open unless they hold a
    point (0: none kept). A sampling hole as wide as the opening would otherwise close it.

    The moving rows' clusters are joined at single-linkage distance ``link`` m.
    """

    gap: float
    keep_open: float
    resolution: float = 0.1
    max_cells: int = 2_000_000
    pad: float = 1.5
    corridor_radius: float = 0.0
    corridor_length: float = 0.0
    link: float = 1.0

    def __post_init__(self):
        check_fields(self, positive=("gap", "keep_open", "resolution", "pad", "link"), integers=("max_cells",),
                     non_negative=("corridor_radius", "corridor_length"))

    def fit(self, points: np.ndarray, mask: np.ndarray, previous: np.ndarray, previous_mask: np.ndarray,
            dt: float, goal: np.ndarray) -> GridFit:
        """The fit of the padded cloud (P, 3) with mask (P,) given the previous observation (P, 3),
        (P,) dt seconds earlier (none at first): the grid of the rows that did not move, around the
        goal (a position (3,) m, or a pose (4, 4) whose approach corridor is kept open), and the
        polytopes of those that did."""
        points, mask = np.asarray(points), np.asarray(mask)
        static, velocity = observed_motion(points, mask, previous, previous_mask, dt)
        moved = mask & np.asarray(previous_mask) & ~static
        goal = np.asarray(goal, np.float64)
        position = goal[:3, 3] if goal.shape == (4, 4) else goal
        ends = [position - self.corridor_length * goal[:3, 2]] if goal.shape == (4, 4) and self.corridor_radius else []
        anchors = np.stack([BASE, *ends, position])
        grid, parts = _fit(np.ascontiguousarray(points[static], np.float64).tobytes(), anchors.tobytes(), bool(ends),
                           self)
        return GridFit(grid, parts, fit_polytopes(points[moved], self.link, velocity=velocity[moved], bounds=()))


def grid_box(points: np.ndarray, anchors: np.ndarray, model: GridModel) -> tuple[np.ndarray, float, tuple]:
    """The grid's origin (3,), spacing and shape (3 ints) for the points and anchors (N, 3)."""
    both = np.concatenate([points, anchors])
    lower = both.min(axis=0) - model.pad - REACH * model.gap
    extent = both.max(axis=0) + model.pad + REACH * model.gap - lower
    h = max(model.resolution, float(np.prod(extent) / model.max_cells) ** (1.0 / 3.0))
    while np.prod(np.ceil(extent / h) + 1) > model.max_cells:  # the cells' rounding up
        h *= 1.01
    return lower, h, tuple(int(n) for n in np.ceil(extent / h).astype(int) + 1)


def border_labels(labels: np.ndarray) -> np.ndarray:
    """The labels (> 0) of ``ndimage.label``'s components that touch the grid's border."""
    border = np.concatenate([labels[[0, -1]].ravel(), labels[:, [0, -1]].ravel(), labels[:, :, [0, -1]].ravel()])
    return np.unique(border[border > 0])


def surfaces(cells: np.ndarray, link: float, h: float) -> list[np.ndarray]:
    """The hit cells (N, 3 ints) split into surfaces: the components of the graph that joins two
    cells at most ``link`` m apart."""
    pairs = cKDTree(cells * h).query_pairs(link, output_type="ndarray")
    graph = coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(len(cells), len(cells)))
    count, labels = connected_components(graph, directed=False)
    return [cells[labels == k] for k in range(count)]


class Surface(NamedTuple):
    """One surface's hit cells in a box of the grid: the box (3 slices), the hit cells there
    (bool) and every cell's distance to them, m (both the box's shape)."""

    box: tuple
    hit: np.ndarray
    distance: np.ndarray


def surface_boxes(parts: list[np.ndarray], shape: tuple, h: float, reach: float) -> list[Surface]:
    """Each surface's hit cells (N, 3 ints) in the box that holds them grown by up to ``reach`` m,
    with their distance transform (computed once for every closing at a reach up to that)."""
    margin = int(np.ceil(reach / h)) + 1
    boxes = []
    for cells in parts:
        low, high = np.maximum(cells.min(axis=0) - margin, 0), np.minimum(cells.max(axis=0) + margin + 1, shape)
        hit = np.zeros(high - low, bool)
        hit[tuple((cells - low).T)] = True
        box = tuple(slice(a, b) for a, b in zip(low, high))
        boxes.append(Surface(box, hit, ndimage.distance_transform_edt(~hit, sampling=h)))
    return boxes


def closed_cells(surfaces: list[Surface], shape: tuple, h: float, reach: float, gap: float) -> np.ndarray:
    """(X, Y, Z) bool: each surface's hit cells grown by ``reach`` m (at most the reach of its
    box) and shrunk by ``sqrt(reach^2 - gap^2)`` on its own (module docstring), enclosed free
    space filled."""
    closed = np.zeros(shape, bool)
    shrink = np.sqrt(max(reach**2 - gap**2, 0.0))
    for surface in surfaces:
        grown = surface.distance <= reach
        closed[surface.box] |= surface.hit | (ndimage.distance_transform_edt(grown, sampling=h) > shrink)
    labels, _ = ndimage.label(~closed)
    return closed | ~np.isin(labels, border_labels(labels))


def signed_field(closed: np.ndarray, hit: np.ndarray, points: np.ndarray, origin: np.ndarray,
                 h: float) -> np.ndarray:
    """(X, Y, Z) float32: the field of the module docstring, m (the whole grid closed: minus the
    grid's diagonal), for the ``hit`` cells of ``points`` (N, 3) on the grid at ``origin``."""
    if closed.all():
        return np.full(closed.shape, -h * float(np.linalg.norm(closed.shape)), np.float32)
    to_hits = ndimage.distance_transform_edt(~hit, sampling=h) - h * np.sqrt(3.0) / 2.0
    filled = closed & ~hit
    to_filled = ndimage.distance_transform_edt(~filled, sampling=h) if filled.any() else np.inf
    near = ~closed & (to_hits <= EXACT_BAND)
    to_hits[near] = cKDTree(points).query(origin + h * np.argwhere(near), workers=-1)[0]
    inside = ndimage.distance_transform_edt(closed, sampling=h)
    return np.where(closed, -inside, np.minimum(to_hits, to_filled)).astype(np.float32)


def goal_open(field: np.ndarray, cell: tuple, room: float) -> bool:
    """Whether cells with a field of at least ``room`` m lead from ``cell`` to the grid's border."""
    labels, _ = ndimage.label(field >= room)
    return bool(np.isin(labels[cell], border_labels(labels)))


@functools.lru_cache(maxsize=GRID_CACHE)
def _fit(data: bytes, anchors: bytes, corridor: bool, model: GridModel) -> tuple[Grid, Polytopes]:
    """The grid and the convex parts' polytopes of the points (bytes of (P, 3)) round the anchors
    (bytes of (N, 3): the base, with a ``corridor`` its far end, and the goal position): the
    points cut into parts (``ncedf.parts``), the ``MAX_CLUSTERS`` largest convex ones closed as
    polytopes, the others closed on the grid, on the device (cached: not copied each step)."""
    points = np.frombuffer(data, np.float64).reshape(-1, 3)
    anchors = np.frombuffer(anchors, np.float64).reshape(-1, 3)
    origin, h, shape = grid_box(points, anchors, model)
    if len(points) == 0:  # no static obstacle: far everywhere
        return padded(origin, h, np.full((2, 2, 2), FAR, np.float32), model.max_cells), on_device(pack([]))
    convex = [part for part in split(points, model.gap) if is_convex(points[part], model.gap, INNER * REACH)]
    closed = sorted(convex, key=len, reverse=True)[:MAX_CLUSTERS]
    rest = np.ones(len(points), bool)
    rest[np.concatenate(closed or [np.zeros(0, int)])] = False
    field = _field(points[rest], anchors, corridor, model, origin, h, shape)
    parts = pack([(part, fit_part(points[part], model.gap)) for part in closed])
    goal = goal_cell(anchors[-1], origin, h, shape)
    if closed and not goal_open(np.minimum(field, parts_field(parts, origin, h, shape)), goal, model.keep_open):
        # The parts shut the goal in: all on the grid, whose closing shrinks until a way opens.
        field, parts = _field(points, anchors, corridor, model, origin, h, shape), pack([])
    return padded(origin, h, field, model.max_cells), on_device(parts)


def on_device(polytopes: Polytopes) -> Polytopes:
    """The polytopes' arrays on the device (a cached fit is not copied each step, nor changed in place)."""
    return jax.tree.map(jnp.asarray, polytopes)


def goal_cell(goal: np.ndarray, origin: np.ndarray, h: float, shape: tuple) -> tuple:
    """The cell (3 ints) of the grid at ``origin`` with spacing h and ``shape`` nearest the goal (3,) m."""
    return tuple(np.clip(np.rint((goal - origin) / h).astype(int), 0, np.asarray(shape) - 1))


def parts_field(parts: Polytopes, origin: np.ndarray, h: float, shape: tuple) -> np.ndarray:
    """(X, Y, Z) the polytopes' distance (``ncedf.convex.polytope_distance``) at the centres of the
    cells of the grid at ``origin`` with spacing h, m: the centres padded to a bucket's size, so that
    grids of other shapes share the compiled program."""
    centres = (origin + h * np.stack(np.indices(shape), axis=-1)).reshape(-1, 3)
    padded = np.zeros((bucket(len(centres)), 3), np.float32)
    padded[:len(centres)] = centres
    return np.asarray(polytope_distance(jnp.asarray(padded), parts))[:len(centres)].reshape(shape)


def _field(points: np.ndarray, anchors: np.ndarray, corridor: bool, model: GridModel, origin: np.ndarray,
           h: float, shape: tuple) -> np.ndarray:
    """(X, Y, Z) the field (module docstring) of the points (P, 3) on the grid at ``origin`` with
    spacing h; far everywhere without points."""
    if len(points) == 0:
        return np.full(shape, FAR, np.float32)
    cells = np.unique(np.rint((points - origin) / h).astype(int), axis=0)
    hit = np.zeros(shape, bool)
    hit[tuple(cells.T)] = True
    reach = REACH * model.gap
    parts = surface_boxes(surfaces(cells, LINK * model.gap, h), shape, h, reach)
    goal = goal_cell(anchors[-1], origin, h, shape)
    way_in = np.zeros(shape, bool)
    if corridor:
        way_in = near_segment(shape, origin, h, anchors[-2:], model.corridor_radius) & ~hit

    def field_at(reach: float) -> np.ndarray:
        closed = (closed_cells(parts, shape, h, reach, model.gap)
                  & closed_cells(parts, shape, h, INNER * reach, model.gap))
        return signed_field(closed & ~way_in, hit, points, origin, h)

    field = field_at(reach)
    while reach > h and not goal_open(field, goal, model.keep_open):
        reach *= SHRINK
        field = field_at(reach)
    return field


def near_segment(shape: tuple, origin: np.ndarray, h: float, ends: np.ndarray, radius: float) -> np.ndarray:
    """(X, Y, Z) bool: the cells whose centres lie within ``radius`` m of the segment between the
    two points ``ends`` (2, 3) m, on the grid of ``shape`` at ``origin`` with spacing ``h``."""
    low = np.maximum(np.floor((ends.min(axis=0) - radius - origin) / h).astype(int), 0)
    high = np.minimum(np.ceil((ends.max(axis=0) + radius - origin) / h).astype(int) + 1, shape)
    index = np.stack(np.meshgrid(*[np.arange(a, b) for a, b in zip(low, high)], indexing="ij"), axis=-1)
    centres = origin + h * index
    axis = ends[1] - ends[0]
    t = np.clip((centres - ends[0]) @ axis / max(float(axis @ axis), 1e-12), 0.0, 1.0)
    near = np.linalg.norm(centres - ends[0] - t[..., None] * axis, axis=-1) <= radius
    out = np.zeros(shape, bool)
    out[tuple(slice(a, b) for a, b in zip(low, high))] = near
    return out


def corners(grid: Grid, x: jnp.ndarray) -> tuple[jnp.ndarray, jnp.ndarray]:
    """The eight cells around each point x (..., 3) clamped into the grid: their values (..., 8)
    and trilinear weights (..., 8)."""
    size = grid.shape.astype(x.dtype)
    u = jnp.clip((x - grid.origin) / grid.spacing, 0.0, size - 1.0)
    low = jnp.clip(jnp.floor(u), 0, size - 2).astype(jnp.int32)
    frac = u - low
    bits = jnp.asarray([[i >> 2 & 1, i >> 1 & 1, i & 1] for i in range(8)], jnp.int32)  # (8, 3)
    weights = jnp.prod(jnp.where(bits == 1, frac[..., None, :], 1.0 - frac[..., None, :]), axis=-1)
    index = low[..., None, :] + bits
    return at_cells(grid, index[..., 0], index[..., 1], index[..., 2]), weights


def at_cells(grid: Grid, i: jnp.ndarray, j: jnp.ndarray, k: jnp.ndarray) -> jnp.ndarray:
    """(...,) the grid's values at the cells of indices i, j, k (...,) int, each within its shape."""
    return grid.values[(i * grid.shape[1] + j) * grid.shape[2] + k]


@jax.jit
def grid_distance(grid: Grid, x: jnp.ndarray) -> jnp.ndarray:
    """(...,) lower bound of the distance from points x (..., 3) to the observed static points, m
    (module docstring; negative inside the closed surfaces)."""
    x = jnp.moveaxis(x, -1, 0)  # one array per coordinate: several times faster on a CPU than (..., 3)
    origin, h, size = grid.origin, grid.spacing, grid.shape.astype(x.dtype)
    q = [jnp.clip(x[a], origin[a], origin[a] + h * (size[a] - 1)) for a in range(3)]  # the box's nearest point
    cell = [jnp.clip(jnp.rint((q[a] - origin[a]) / h), 0, size[a] - 1) for a in range(3)]
    to_centre = sum((q[a] - origin[a] - h * cell[a]) ** 2 for a in range(3))
    at_q = at_cells(grid, *[c.astype(jnp.int32) for c in cell]) - jnp.sqrt(to_centre)
    out = sum((x[a] - q[a]) ** 2 for a in range(3))
    return jnp.where(out > 0, jnp.sqrt(out + jnp.maximum(at_q, 0.0) ** 2), at_q)


def nearer(d: jnp.ndarray, x: jnp.ndarray, polytopes: Polytopes, t=0.0, turning: bool = False) -> jnp.ndarray:
    """(...,) the distances d (...,) of the points x (..., 3), or their distance to the polytopes
    (``ncedf.convex.polytope_distance``) where less; skipped where no polytope is present."""
    return jax.lax.cond(jnp.any(polytopes.present),
                        lambda: jnp.minimum(d, polytope_distance(x, polytopes, t, turning=turning)), lambda: d)


@jax.jit
def still_distance(fit: GridFit, x: jnp.ndarray) -> jnp.ndarray:
    """(...,) lower bound of the distance from points x (..., 3) to the still points of the fit, m:
    the grid's bound (:func:`grid_distance`) or the convex parts' distance, whichever is less (each
    part's polytope holds its points' hull)."""
    return nearer(grid_distance(fit.grid, x), x, fit.parts)


@jax.jit
def smooth_distance(fit: GridFit, x: jnp.ndarray) -> jnp.ndarray:
    """(...,) the still points' field at points x (..., 3) interpolated trilinearly between its cell
    values, or the parts' distance where less, m: continuous, its gradient pointing away from the
    points (to climb clear of them, ``ncedf.route``); not a bound, unlike :func:`still_distance`."""
    values, weights = corners(fit.grid, x)
    return nearer(jnp.sum(values * weights, axis=-1), x, fit.parts)


def fit_clearance(arcs: jnp.ndarray, frames: jnp.ndarray, spec: RobotSpec, fit: GridFit, t=0.0,
                  turning: bool = False) -> jnp.ndarray:
    """(B...,) lower bound of the clearance of the bodies (arcs (B..., M, 3), their frames
    (B..., M + 1, 4, 4)) to the fit, its moving polytopes moved ``t`` s ahead (``turning``: anywhere
    within their speed times t, ``ncedf.convex.polytope_distance``; B... the broadcast of the batch
    shapes of arcs and t), m: the least over the cover balls, whose centres serve the grid and the
    polytopes both (the polytopes skipped where none is present; the first link's balls without the
    parts marked as under its base plane, ``ncedf.mount``)."""
    cover = SphereShape(spec, per_link=COVER_SPHERES)
    batch = jnp.broadcast_shapes(arcs.shape[:-2], jnp.shape(t))
    flat_arcs = jnp.broadcast_to(arcs, batch + arcs.shape[-2:]).reshape((-1,) + arcs.shape[-2:])
    flat_frames = jnp.broadcast_to(frames, batch + frames.shape[-3:]).reshape((-1,) + frames.shape[-3:])
    time = jnp.broadcast_to(jnp.asarray(t, arcs.dtype), batch).reshape(-1, 1, 1)
    geom = jax.vmap(cover.prepare)(flat_arcs, flat_frames)  # centres (B, M, n, 3), radius (B, M)
    first = None if fit.parts.mount is None else fit._replace(parts=for_first_link(fit.parts))
    d = per_link(lambda model, x: nearer(still_distance(model, x), x, model.moving, time, turning), fit, first,
                 geom.centres)  # (B, M, n)
    return jnp.min(d - geom.radius[..., None], axis=(-2, -1)).reshape(batch)
