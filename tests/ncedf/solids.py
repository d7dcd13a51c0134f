"""Surface samples of solids with holes (the obstacle model's convexity rule) and of spheres."""

import numpy as np


def surface(solid, spacing=(0.125, 0.25, 0.25), offset=(0.0, 0.0, 0.0)) -> np.ndarray:
    """Grid points of the solid (a predicate on (P, 3) points) with a grid neighbour outside it:
    samples of its surface, the inner faces of its holes included; shifted by ``offset``, m."""
    axes = [np.arange(-3.0, 5.0 + 1e-9, h) for h in spacing]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    outer = np.zeros(len(grid), bool)
    for step in np.concatenate([np.diag(spacing), -np.diag(spacing)]):
        outer |= ~solid(grid + step)
    return (grid[solid(grid) & outer] + np.asarray(offset)).astype(np.float32)


def wall(points, port: bool) -> np.ndarray:
    """A wall 0.5 m thick (x in [0, 0.5], y in [-2, 2], z in [0, 4]), with a 1 m square port at y = 0, z = 2."""
    x, y, z = points.T
    inside = (x >= -1e-9) & (x <= 0.5 + 1e-9) & (np.abs(y) <= 2 + 1e-9) & (z >= -1e-9) & (z <= 4 + 1e-9)
    hole = (np.abs(y) < 0.5 - 1e-9) & (np.abs(z - 2.0) < 0.5 - 1e-9)
    return inside & ~hole if port else inside


def solid_wall(**grid) -> np.ndarray:
    """Surface samples of the wall without its port (``surface``'s spacing and offset)."""
    return surface(lambda p: wall(p, port=False), **grid)


def ported_wall(**grid) -> np.ndarray:
    """Surface samples of the wall with its port, the port's inner faces included."""
    return surface(lambda p: wall(p, port=True), **grid)


def sphere_surface(rng, centre, radius, n) -> np.ndarray:
    """n uniform points on a sphere, float32 as the scenarios observe them."""
    d = rng.normal(size=(n, 3))
    return (np.asarray(centre) + radius * d / np.linalg.norm(d, axis=1, keepdims=True)).astype(np.float32)
