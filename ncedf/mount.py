"""The mount: the surface under the robot's base, which its first link cannot reach.

A robot stands on something (a floor, a table): observed points at or just below its base. Every
bound of the first link near its base reaches below the base plane (a covering ball of the base
disk dips by nearly its radius), so with such points in the cloud or in the obstacle model no
state keeps the safety margin, and the robot holds still. Yet the first link never goes below
the plane:

In its base frame (the world's: base at the origin, first tangent +z) link 1 bends at constant
curvature k = theta / L, theta <= ``spec.max_bend()``. Its cross-section at arc s is a disk of
radius r centred on the backbone at height sin(k s) / k, tilted by k s from horizontal; its lowest
point lies at sin(k s) (1 / k - r) >= 0 wherever k s <= pi and k r <= 1. The end disks are the
cross-sections at s = 0 and L. So the body lies in z >= 0: a point at height z <= 0 is at least
-z from it, never inside.

Hence, with a :class:`Mount`, the mount's points (at or below the plane within ``reach`` of the base's
axis) do not count for the first link (:func:`link_mask`; every other link keeps them), the grid
model is fitted without them (:func:`off_mount`: the hole they leave under the base, of radius
``reach``, stays open where the holes the grid closes between samples are smaller, their radius
``Observation.gap``; a sparser floor is closed over it again, and the robot held still as before),
and the fitted polytopes wholly under the plane are no obstacle to the first link (:func:`marked`:
a convex hull of the floor round the hole would cover it again).
"""

from __future__ import annotations

import dataclasses
import math

import jax.numpy as jnp
import numpy as np

from ncedf.convex import Polytopes
from ncedf.grid_model import GridFit
from ncedf.robot import RobotSpec
from ncedf.validate import check_fields


@dataclasses.dataclass(frozen=True)
class Mount:
    """The mount's extent (module docstring): points with z <= 0 within ``reach`` m of the z axis."""

    reach: float

    def __post_init__(self):
        check_fields(self, positive=("reach",))


def holds(spec: RobotSpec) -> bool:
    """Whether the first link of ``spec`` stays above its base plane (module docstring: a bend of at
    most pi, curvature times radius at most 1)."""
    bend = spec.max_bend()
    return bend <= math.pi and bend * spec.radii[0] <= spec.length


def on_mount(mount: Mount, points):
    """(P,) bool: the points (P, 3) on the mount."""
    x, y, z = points[..., 0], points[..., 1], points[..., 2]
    return (z <= 0.0) & (x * x + y * y <= mount.reach * mount.reach)


def link_mask(mount: Mount | None, points: np.ndarray, mask: np.ndarray, n_links: int) -> np.ndarray:
    """The points (P, 3) each link is scored against: (M, P), ``mask`` (P,) with the mount's points
    off for the first link; ``mask`` itself where none of its points is on the mount."""
    on = np.zeros(len(mask), bool) if mount is None else on_mount(mount, np.asarray(points)) & mask
    if not on.any():
        return mask
    out = np.repeat(np.asarray(mask)[None], n_links, axis=0)
    out[0] &= ~on
    return out


def off_mount(mount: Mount | None, points: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """(P,) ``mask`` less the mount's points: what the grid model is fitted to."""
    return mask if mount is None else mask & ~on_mount(mount, np.asarray(points))


def marked(mount: Mount | None, fitted: Polytopes | GridFit | None):
    """``fitted`` with its still polytopes (a grid fit's convex parts) that lie wholly under the base
    plane marked as no obstacle to the first link (``Polytopes.mount``); as it is without a mount or
    where none lies there."""
    if mount is None or fitted is None:
        return fitted
    if isinstance(fitted, GridFit):
        return fitted._replace(parts=marked(mount, fitted.parts))
    top = np.where(np.asarray(fitted.ball), np.asarray(fitted.centre)[:, 2] + np.asarray(fitted.radius),
                   np.asarray(fitted.upper)[:, 2])
    under = np.asarray(fitted.present) & (top <= 0.0) & ~np.any(np.asarray(fitted.velocity) != 0, axis=-1)
    return fitted._replace(mount=jnp.asarray(under)) if under.any() else fitted
