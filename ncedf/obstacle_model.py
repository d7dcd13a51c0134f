"""The obstacle-model stage: what the controller scores besides the observed points.

Without a model the rollouts are scored against the observed cloud alone (the
paper). A cloud sampled sparsely on obstacle surfaces has holes wider than the
robot, and a link can slide into a face between its points. :class:`ConvexModel`
closes each convex cluster of the cloud (``ncedf.convex``): the cloud's rows that
did not move since the previous observation and those that did are clustered
apart (static clusters whose bounding boxes lie within ``link`` merge, so a
sparsely sampled box stays whole), a cluster on a sphere is its ball, a convex
one its polytope, and a static one that is not convex is left to the cloud. Each rollout
state's distance is then the smaller of the representation's and a lower bound
of the body's clearance to the model, every polytope moved at the mean velocity
of its points to the state's time.

:class:`ncedf.grid_model.GridModel` closes the static cloud without assuming convexity
instead: the parts that empty slabs cut apart as polytopes where convex, the rest on
a voxel grid, and the rows seen to move into their clusters' polytopes;
:func:`model_clearance` scores a state against either fit.

The fit runs in numpy outside the jitted step (a static group of points is
fitted once and cached), so it is the controller shell's job
(``ncedf.controller``); this module holds the setting and the fit.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from ncedf.convex import (COVER_SPHERES, Polytopes, fit_polytopes, for_first_link, observed_motion, per_link,
                          polytope_distance, robot_clearance)
from ncedf.grid_model import FAR, GridFit, fit_clearance, nearer, smooth_distance
from ncedf.shapes import SphereShape
from ncedf.validate import check_fields


@dataclasses.dataclass(frozen=True)
class ConvexModel:
    """The convex model of the cloud at single-linkage distance ``link``, m: above the gaps
    between the samples of one obstacle, below the gaps between obstacles."""

    link: float = 1.0

    def __post_init__(self):
        check_fields(self, positive=("link",))

    def fit(self, points: np.ndarray, mask: np.ndarray, previous: np.ndarray, previous_mask: np.ndarray,
            dt: float) -> Polytopes:
        """The polytopes of the padded cloud (P, 3) with mask (P,), given the previous
        observation (P, 3), (P,) (all False at first: every row counts as moving) dt seconds
        earlier. Only the static rows' clusters merge by their bounding boxes (distinct moving
        obstacles would chain together through the boxes of the clusters between them)."""
        points, mask = np.asarray(points), np.asarray(mask)
        static, velocity = observed_motion(points, mask, previous, previous_mask, dt)
        return fit_polytopes(points[mask], self.link, static[mask], velocity[mask], bounds=(True,))


def model_clearance(fitted: Polytopes | GridFit, arcs, frames, spec, t=0.0, turning: bool = False):
    """(B...,) lower bound of the clearance of the states arcs (B..., M, 3) with frames
    (B..., M + 1, 4, 4) to a fitted obstacle model (polytopes moved ``t`` s ahead; ``turning``:
    anywhere within their speed times t, ``ncedf.convex.polytope_distance``), m."""
    if isinstance(fitted, GridFit):
        return fit_clearance(arcs, frames, spec, fitted, t, turning)
    return robot_clearance(arcs, frames, spec, fitted, t, turning=turning)


#: The soft minimum's temperature in :func:`soft_clearance`, m: the cover balls within a few of it
#: of the nearest all count.
SOFTNESS = 0.02


def soft_clearance(fitted: Polytopes | GridFit, arc, frames, spec):
    """() a smooth stand-in for the clearance of one state arc (M, 3) with frames (M + 1, 4, 4) to the
    still part of a fitted model, m: a soft minimum over the cover balls of their distance (the grid's
    interpolated, ``ncedf.grid_model.smooth_distance``), so that its gradient moves every ball near an
    obstacle away from it. For climbing clear, not a bound (:func:`model_clearance` is)."""
    geom = SphereShape(spec, per_link=COVER_SPHERES).prepare(arc, frames)
    parts = fitted.parts if isinstance(fitted, GridFit) else fitted
    first = None  # the first link's balls as model_clearance scores them
    if parts.mount is not None:
        first = fitted._replace(parts=for_first_link(parts)) if isinstance(fitted, GridFit) else for_first_link(parts)
    d = per_link(_soft_distance, fitted, first, geom.centres)
    d = jnp.minimum(d - geom.radius[..., None], FAR)  # no polytope: +inf, whose gradient is NaN
    return -SOFTNESS * jax.nn.logsumexp(-d.ravel() / SOFTNESS)


def _soft_distance(fitted: Polytopes | GridFit, x: jnp.ndarray) -> jnp.ndarray:
    """(...,) the distance :func:`soft_clearance` smooths from points x (..., 3) to the fitted model, m."""
    if isinstance(fitted, GridFit):  # and its still moving group's polytopes, as model_clearance counts them
        return nearer(smooth_distance(fitted, x), x, fitted.moving)
    return polytope_distance(x, fitted)


def static_part(fitted: Polytopes | GridFit) -> Polytopes | GridFit:
    """The fitted model less what moves: its moving polytopes left out."""
    if isinstance(fitted, GridFit):
        return fitted._replace(moving=static_part(fitted.moving))
    return fitted._replace(present=fitted.present & ~np.any(fitted.velocity != 0, axis=-1))


def left_out(fitted: Polytopes | GridFit) -> int:
    """The still obstacles the fitted model misses: the convex model's clusters left out as not convex."""
    return 0 if isinstance(fitted, GridFit) else int(fitted.left_out)
