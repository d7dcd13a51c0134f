"""The still cloud split into obstacles at empty slabs, and which of them are convex.

The grid model (``ncedf.grid_model``) closes a sparsely sampled surface by growing
its samples, which moves every edge out by part of a sampling gap and its bound
loses up to half a cell more: a lane between two pillars narrows by both. A convex
obstacle needs neither: its points' polytope (``ncedf.convex``) closes it exactly
where it is a box and within a chord elsewhere. So the still points are first cut
apart where the samples cannot belong to one surface, and each convex part is
closed as a polytope; only the rest goes to the grid.

A cut (:func:`cut`): along an axis, an interval of width ``s`` that no point's
coordinate falls in. Were one obstacle to cross it, its surface would leave a band
of area ``A`` empty there. With the parts' cross-sections next to the cut spanning
boxes of diagonal ``e`` (the smaller side's), a surface crossing as wide as they are
(a thin rod joining two parts is not ruled out) leaves ``A >= s e`` empty (an open
surface's cross-section is at least its diagonal long). At a density rho such a band
is empty with probability ``exp(-rho A)``, and at the cloud's gap (``pi rho gap^2 =
ln n``, ``ncedf.presets.sampling_gap``) ``n^(-A / (pi gap^2))``. A cut is made where
that is at most ``n^-2`` (``s e >= 2 pi gap^2``; over the at most 3n intervals
looked at, 3/n) and the interval is at least a gap wide (a face's samples are not
cut apart by the narrow empty bands that some of its strips leave). It assumes one
density over the cloud: an obstacle sampled more sparsely than the gap says is cut
more readily. Between two pillars of a row (8 m tall, 0.36 m gaps) that is a gap;
along one pillar (0.5 m across) a band of 1.1 m.

A part is convex (:func:`is_convex`) where it has at least ``MIN_POINTS`` points (fewer
tell a convex surface from a fragment of any other too poorly), they span a volume
(a flat part, a plane's samples, may be a plate with holes), every point lies on
their hull's boundary (``ncedf.convex.hull_depth``: else a concavity holds points)
or on a sphere, and the hull's surface lies within ``cover`` gaps of them (else it
spans an opening wider than a sampling hole: a thin plate's window, whose edges
lie within a plate's thickness of the hull; the grid model gives the span its own
closing fills).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from ncedf.convex import CONVEX_TOLERANCE, convex_hull, fit_sphere, hull_depth, triangle_areas

#: The fewest points of a part closed as convex.
MIN_POINTS = 20
#: Surface samples per square gap that :func:`hull_cover` measures the hull's surface at.
COVER_SAMPLES = 16
#: The share of a cut's sides measured for their cross-section, in gaps from the cut.
NEAR_CUT = 2.0


def cut(points: np.ndarray, gap: float) -> np.ndarray | None:
    """(P,) bool: the points (P, 3) on the lower side of the widest cut (module docstring) at
    holes of radius ``gap`` m, over the three axes; None where there is none."""
    if gap <= 0 or len(points) < 2:
        return None
    whole = np.linalg.norm(np.ptp(points, axis=0))
    best, side = max(gap, 2 * np.pi * gap**2 / max(whole, 1e-12)), None  # no cut is narrower (the whole set across)
    for axis in range(3):
        order = np.argsort(points[:, axis], kind="stable")
        v = points[order, axis]
        others = [a for a in range(3) if a != axis]
        widths = np.diff(v)
        for k in np.argsort(-widths, kind="stable"):
            if widths[k] < best:
                break
            low = points[(v[k] - points[:, axis] <= NEAR_CUT * gap) & (points[:, axis] <= v[k])][:, others]
            high = points[(points[:, axis] - v[k + 1] <= NEAR_CUT * gap) & (points[:, axis] >= v[k + 1])][:, others]
            across = min(np.hypot(*np.ptp(low, axis=0)), np.hypot(*np.ptp(high, axis=0)))
            if widths[k] * across >= 2 * np.pi * gap**2:
                best, side = widths[k], points[:, axis] <= v[k]
                break
    return side


def split(points: np.ndarray, gap: float) -> list[np.ndarray]:
    """The parts of the points (P, 3): the index arrays of the sets left by cutting (:func:`cut`)
    until no cut remains, in the order of the points' first members."""
    todo, parts = [np.arange(len(points))] if len(points) else [], []
    while todo:
        index = todo.pop()
        lower = cut(points[index], gap) if len(index) > 1 else None
        if lower is None:
            parts.append(index)
        else:
            todo += [index[~lower], index[lower]]
    return sorted(parts, key=lambda part: part[0])


def hull_cover(points: np.ndarray, gap: float) -> float:
    """How far from the points (P, 3) their hull's surface reaches, m: the largest distance to them
    of ``COVER_SAMPLES`` surface points per ``gap^2`` drawn on the hull's triangles by area (a fixed
    draw); inf where the points span no volume."""
    hull = convex_hull(points)
    if hull is None:
        return np.inf
    corners = points[hull.simplices]  # (F, 3, 3)
    areas = triangle_areas(corners)
    rng = np.random.default_rng(0)
    count = int(np.ceil(COVER_SAMPLES * areas.sum() / gap**2))
    face = rng.choice(len(areas), count, p=areas / areas.sum())
    u, v = rng.uniform(size=(2, count, 1))
    u, v = np.where(u + v > 1, 1 - u, u), np.where(u + v > 1, 1 - v, v)
    samples = corners[face, 0] + u * (corners[face, 1] - corners[face, 0]) + v * (corners[face, 2] - corners[face, 0])
    return float(cKDTree(points).query(samples)[0].max())


def is_convex(points: np.ndarray, gap: float, cover: float) -> bool:
    """Whether the points (P, 3), sampled with holes of radius ``gap`` m, lie on a convex surface
    whose hull lies within ``cover`` gaps of them (module docstring)."""
    if len(points) < MIN_POINTS or hull_cover(points, gap) > cover * gap:
        return False
    return hull_depth(points) <= CONVEX_TOLERANCE or fit_sphere(points) is not None
