"""The guide stage: the goal cost's distance measured along free space instead of straight.

MPPI is local: where the goal lies behind a wall, reached through a window, every
rollout's straight goal distance says press against the wall. The guide replaces
the tip's straight distance to the goal with its distance along the free space of
the grid model (``ncedf.grid_model``): the shortest path between every
``coarsen``-th cell of the model's grid (26 neighbours; a cell is free where
the model's field and its convex parts' distance are at least ``clearance``,
room for the robot's body round its tip), a step into a cell that is not free
costing ``blocked`` times its length, so that every cell has a finite value
and the path still prefers a long way round to a short way through. The tip's
guided distance is the trilinear interpolation of that field, plus its distance
to the grid where it lies outside. Where the goal is a pose, the guided distance
takes the place of the position's share of the Frobenius distance.

The field is computed once per grid and goal (scipy's Dijkstra, outside the jitted step).
:func:`approach` reads the direction the guided path arrives at the goal along, for the
route recovery's goal states (``ncedf.route``).
"""

from __future__ import annotations

import dataclasses
import itertools

import jax.numpy as jnp
import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import dijkstra

from ncedf.grid_model import Grid, GridFit, corners, padded, parts_field
from ncedf.validate import check_fields

#: The 13 neighbour offsets of a cell that, with their opposites, make its 26.
OFFSETS = np.array([d for d in itertools.product((-1, 0, 1), repeat=3) if d > (0, 0, 0)])


@dataclasses.dataclass(frozen=True)
class Guide:
    """The guide (module docstring): ``clearance`` m of room round the tip's path, guide cells
    ``coarsen`` model cells wide, a step through a cell without room costing ``blocked`` times."""

    clearance: float
    coarsen: int = 2
    blocked: float = 20.0

    def __post_init__(self):
        check_fields(self, positive=("clearance", "blocked"), integers=("coarsen",))

    def fit(self, fitted: GridFit, goal) -> Grid:
        """The guided distance to the goal position (3,) m on the grid of the model's fit, m (room
        where the grid's field and the convex parts' distance both leave it)."""
        k, grid = self.coarsen, fitted.grid
        room = grid.array()[::k, ::k, ::k]
        h, origin = float(grid.spacing) * k, np.asarray(grid.origin, np.float64)
        if np.any(fitted.parts.present):
            room = np.minimum(room, parts_field(fitted.parts, origin, h, room.shape))
        field = path_lengths(room >= self.clearance, h, self.blocked, np.asarray(goal, np.float64) - origin)
        return padded(origin, h, field, int(grid.values.size))


def path_lengths(free: np.ndarray, h: float, blocked: float, goal: np.ndarray) -> np.ndarray:
    """(X, Y, Z) the length of the shortest path from each cell to the point ``goal`` (3,) (m,
    relative to cell (0, 0, 0)), by steps between neighbours, a step ``blocked`` times its
    length where either cell is not free, plus the goal's distance to its nearest cell."""
    shape = np.asarray(free.shape)
    index = np.arange(free.size).reshape(free.shape)
    rows, cols, weights = [], [], []
    for offset in OFFSETS:
        source = tuple(slice(max(0, -d), n - max(0, d)) for d, n in zip(offset, shape))
        target = tuple(slice(max(0, d), n - max(0, -d)) for d, n in zip(offset, shape))
        both = free[source] & free[target]
        rows.append(index[source].ravel())
        cols.append(index[target].ravel())
        weights.append((h * float(np.linalg.norm(offset)) * np.where(both, 1.0, blocked)).ravel())
    graph = coo_matrix((np.concatenate(weights), (np.concatenate(rows), np.concatenate(cols))),
                       shape=(free.size, free.size)).tocsr()
    cell = np.clip(np.rint(goal / h).astype(int), 0, shape - 1)
    start = np.linalg.norm(goal - h * cell)
    return dijkstra(graph, directed=False, indices=int(index[tuple(cell)])).reshape(free.shape) + start


def guided_distance(field: Grid, x: jnp.ndarray) -> jnp.ndarray:
    """(...,) the guided distance of points x (..., 3) to the goal, m: the field's trilinear
    interpolation at x clamped into the grid, plus the distance from x to that point."""
    values, weights = corners(field, x)
    inside = jnp.clip(x, field.origin, field.origin + field.spacing * (field.shape - 1).astype(x.dtype))
    return jnp.sum(weights * values, axis=-1) + jnp.sqrt(jnp.sum((x - inside) ** 2, axis=-1))


def descent(field: Grid, start) -> np.ndarray:
    """(K, 3) the centres of the cells from the one nearest ``start`` (3,) m, each the neighbour
    (of 26) of least value, until none is lower: the guided path towards the goal, m."""
    values, h = field.array(), float(field.spacing)
    origin, shape = np.asarray(field.origin, np.float64), np.asarray(values.shape)
    cell = np.clip(np.rint((np.asarray(start, np.float64) - origin) / h).astype(int), 0, shape - 1)
    steps = np.concatenate([OFFSETS, -OFFSETS])
    path = [cell]
    while True:
        around = np.clip(cell + steps, 0, shape - 1)
        best = int(np.argmin(values[tuple(around.T)]))
        if values[tuple(around[best])] >= values[tuple(cell)]:
            return origin + h * np.asarray(path, np.float64)
        cell = around[best]
        path.append(cell)


def approach(field: Grid, start, goal, back: float) -> np.ndarray | None:
    """The unit vector (3,) along which the guided path from ``start`` (3,) m arrives at the goal:
    the field's descent direction (minus its gradient, central differences) at the path's last cell
    at least ``back`` m from the goal by the field (the start's where none is); None where it is flat."""
    path = descent(field, start)
    values, h = field.array().astype(np.float64), float(field.spacing)
    cells = np.rint((path - np.asarray(field.origin)) / h).astype(int)
    far = values[tuple(cells.T)] >= back
    cell = cells[np.flatnonzero(far)[-1]] if far.any() else cells[0]
    slope = -_gradient_at(values, cell, h)
    length = float(np.linalg.norm(slope))
    return slope / length if length > 0 else None


def _gradient_at(values: np.ndarray, cell: np.ndarray, h: float) -> np.ndarray:
    """(3,) ``np.gradient(values, h)`` at one cell (3 ints) without the whole grid's: central
    differences inside, one-sided ones on the border."""
    out = np.zeros(3)
    for k in range(3):
        lo, hi = cell.copy(), cell.copy()
        lo[k], hi[k] = max(cell[k] - 1, 0), min(cell[k] + 1, values.shape[k] - 1)
        out[k] = (values[tuple(hi)] - values[tuple(lo)]) / (h * (hi[k] - lo[k]))
    return out
