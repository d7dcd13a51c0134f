"""Training and validation sets for one link's CEDF (paper Sec. IV-B).

A training set holds, for each of ``n_configs`` random link configurations,
the workspace points of a ``grid^3`` lattice over the box and ``n_surface``
points on the link surface (label 0), each labelled with its distance to the
link surface. Labels are exact (closed form, ``ncedf.geometry``) or, for
comparison with the paper, the distance to the nearest of the sampled surface
points. ``n_near`` optional extra points per configuration, drawn around the
surface (beyond the paper), put more samples where collisions are decided.

A validation set uses other random configurations and uniformly random points
in the same box, plus surface points to check the prediction there.

Sets are cached on disk as ``.npz`` keyed by a hash of their settings
(folder: ``$NCEDF_CACHE`` or ``~/.cache/ncedf``).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from ncedf.geometry import link_signed_distance, sample_link_surface
from ncedf.robot import RobotSpec, arc_lengths_to_config, sample_arc_lengths

LABELS = ("exact", "surface-samples")
BOX_MIN = (-2.5, -2.5, -1.0)
BOX_MAX = (2.5, 2.5, 3.0)


@dataclasses.dataclass(frozen=True)
class DatasetConfig:
    """Settings of a training set (defaults: paper Sec. IV-B / VI-A).

    Attributes:
      n_configs: link configurations N.
      grid: workspace lattice points per axis (N_w = grid^3).
      n_surface: surface points per configuration N_s (label 0).
      n_near: extra points per configuration, surface points displaced by
        N(0, near_sigma^2) noise per axis (0 = the paper's set).
      near_sigma: standard deviation of that displacement, m.
      labels: "exact" or "surface-samples" (the paper's approximation).
      box_min, box_max: workspace box in the link frame, m.
      seed: PRNG seed.
    """

    n_configs: int = 250
    grid: int = 32
    n_surface: int = 1600
    n_near: int = 0
    near_sigma: float = 0.1
    labels: str = "exact"
    box_min: tuple[float, float, float] = BOX_MIN
    box_max: tuple[float, float, float] = BOX_MAX
    seed: int = 0

    def __post_init__(self):
        for name in ("n_configs", "grid"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        for name in ("n_surface", "n_near"):
            if getattr(self, name) < 0:
                raise ValueError(f"{name} must be >= 0, got {getattr(self, name)}")
        if self.labels not in LABELS:
            raise ValueError(f"labels must be one of {LABELS}, got {self.labels!r}")
        if not all(lo < hi for lo, hi in zip(self.box_min, self.box_max)):
            raise ValueError(f"box_min {self.box_min} must be below box_max {self.box_max}")


@dataclasses.dataclass(frozen=True)
class ValidationConfig:
    """Settings of a validation set: other configurations, uniform box points.

    Attributes:
      n_configs: link configurations.
      n_points: uniformly random points per configuration.
      n_surface: surface points per configuration (to check predictions there).
      seed: PRNG seed (keep it different from the training seed).
    """

    n_configs: int = 100
    n_points: int = 4096
    n_surface: int = 256
    box_min: tuple[float, float, float] = BOX_MIN
    box_max: tuple[float, float, float] = BOX_MAX
    seed: int = 12345

    def __post_init__(self):
        for name in ("n_configs", "n_points", "n_surface"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")


@dataclasses.dataclass(frozen=True)
class LinkDataset:
    """Labelled samples per configuration.

    Attributes:
      theta, phi: (N,) configurations, rad.
      points: (N, K, 3) link-frame points, m.
      distances: (N, K) distance labels (unsigned), m.
      inside: (N, K) whether each point lies inside the link (exact geometry).
      surface: (N, S, 3) surface points (label 0), m; S may be 0.
      key: cache key (hash of the settings).
    """

    theta: np.ndarray
    phi: np.ndarray
    points: np.ndarray
    distances: np.ndarray
    inside: np.ndarray
    surface: np.ndarray
    key: str

    @property
    def n_samples(self) -> int:
        return int(self.distances.size + self.surface.shape[0] * self.surface.shape[1])


def settings_hash(config, spec: RobotSpec) -> str:
    """Stable hash of dataset settings and the link geometry (16 hex digits)."""
    payload = {
        "kind": type(config).__name__,
        "config": dataclasses.asdict(config),
        "spec": spec.link_geometry(),
        "version": 2,
    }
    return hashlib.sha256(json.dumps(payload, sort_keys=True).encode()).hexdigest()[:16]


def cache_dir() -> Path:
    return Path(os.environ.get("NCEDF_CACHE", Path.home() / ".cache" / "ncedf"))


def grid_points(grid: int, box_min, box_max) -> jnp.ndarray:
    """The grid^3 lattice over the box, (grid^3, 3), m."""
    axes = [jnp.linspace(lo, hi, grid) for lo, hi in zip(box_min, box_max)]
    return jnp.stack(jnp.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)


def random_configs(key, n: int, spec: RobotSpec) -> tuple[jnp.ndarray, jnp.ndarray]:
    """(theta, phi), each (n,), of random valid link states (paper Sec. IV-B)."""
    return arc_lengths_to_config(sample_arc_lengths(key, spec, (n,)), spec)


def _exact_labels(points, theta, phi, spec):
    """Unsigned exact distance (P,) and inside flags (P,)."""
    sd = link_signed_distance(points, theta, phi, spec)
    return jnp.abs(sd), sd < 0


def _surface_sample_distance(points, surface):
    """Distance to the nearest of the surface samples, (K,); chunked over points."""
    def nearest(chunk):
        d2 = jnp.sum((chunk[:, None, :] - surface[None, :, :]) ** 2, axis=-1)
        return jnp.sqrt(jnp.min(d2, axis=1))

    return jax.lax.map(nearest, points.reshape(-1, 512, 3)).reshape(-1)


def _build_training(config: DatasetConfig, spec: RobotSpec):
    key = jax.random.PRNGKey(config.seed)
    k_cfg, k_surf, k_near_base, k_near_noise = jax.random.split(key, 4)
    theta, phi = random_configs(k_cfg, config.n_configs, spec)
    grid = grid_points(config.grid, config.box_min, config.box_max)
    n = config.n_configs
    surf_keys = jax.random.split(k_surf, n)
    near_keys = jax.random.split(k_near_base, n)
    noise_keys = jax.random.split(k_near_noise, n)

    def one(theta, phi, k_s, k_n, k_noise):
        surface = sample_link_surface(k_s, config.n_surface, theta, phi, spec)
        near = sample_link_surface(k_n, config.n_near, theta, phi, spec)
        near = near + config.near_sigma * jax.random.normal(k_noise, near.shape)
        points = jnp.concatenate([grid, near], axis=0)
        dist, inside = _exact_labels(points, theta, phi, spec)
        if config.labels == "surface-samples":
            pad = (-points.shape[0]) % 512
            padded = jnp.concatenate([points, jnp.zeros((pad, 3))], axis=0)
            dist = _surface_sample_distance(padded, surface)[: points.shape[0]]
        return points, dist, inside, surface

    points, dist, inside, surface = jax.lax.map(
        lambda args: one(*args), (theta, phi, surf_keys, near_keys, noise_keys)
    )
    return theta, phi, points, dist, inside, surface


def _build_validation(config: ValidationConfig, spec: RobotSpec):
    key = jax.random.PRNGKey(config.seed)
    k_cfg, k_pts, k_surf = jax.random.split(key, 3)
    theta, phi = random_configs(k_cfg, config.n_configs, spec)
    lo, hi = jnp.asarray(config.box_min), jnp.asarray(config.box_max)
    points = jax.random.uniform(k_pts, (config.n_configs, config.n_points, 3), minval=lo, maxval=hi)
    surf_keys = jax.random.split(k_surf, config.n_configs)
    dist, inside = jax.vmap(_exact_labels, in_axes=(0, 0, 0, None))(points, theta, phi, spec)
    surface = jax.vmap(sample_link_surface, in_axes=(0, None, 0, 0, None))(
        surf_keys, config.n_surface, theta, phi, spec
    )
    return theta, phi, points, dist, inside, surface


FIELDS = ("theta", "phi", "points", "distances", "inside", "surface")


def load_dataset(config: DatasetConfig | ValidationConfig, spec: RobotSpec, use_cache: bool = True) -> LinkDataset:
    """Build (or read from the cache) the set described by ``config``."""
    key = settings_hash(config, spec)
    path = cache_dir() / f"{type(config).__name__.lower()}-{key}.npz"
    if use_cache and path.exists():
        try:
            with np.load(path) as f:
                return LinkDataset(**{k: f[k] for k in FIELDS}, key=key)
        except (OSError, ValueError, KeyError):
            path.unlink(missing_ok=True)
    build = _build_training if isinstance(config, DatasetConfig) else _build_validation
    arrays = jax.jit(build, static_argnums=(0, 1))(config, spec)
    arrays = [np.asarray(a, dtype=bool if a.dtype == bool else np.float32) for a in arrays]
    data = LinkDataset(*arrays, key=key)
    if use_cache:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(f".tmp{os.getpid()}.npz")
        np.savez(tmp, **{k: getattr(data, k) for k in FIELDS})
        os.replace(tmp, path)
    return data
