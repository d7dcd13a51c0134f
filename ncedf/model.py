"""The N-CEDF: a per-link MLP composed through the kinematic chain (paper Sec. IV).

``Gamma(p, q) = min_i Gamma_i(T_0i^-1 p, q_i)`` (paper eq. 5-6), with one
network ``Gamma_i`` shared by all links when they have the same geometry, and one
per link for a tapered robot (its parameters stacked along a leading link axis).

Input encodings of a link-frame point ``p`` and the link's (theta, phi):
  ``paper``          (theta, phi, x, y, z), as in the paper;
  ``bending-plane``  (theta, x', y', z') with ``p' = Rz(-phi) p``: the link then
                     always bends towards +x, so the network needs not learn the
                     rotational symmetry about z, nor the wrap-around of phi.

Outside the box it was trained in (its *domain*, link frame) a network
extrapolates. There its output is clamped between bounds of the true
distance from the link's chord (its end points' segment): the link's backbone
lies within the sagitta ``h`` of the chord (an arc of angle <= pi), so for a
point outside the link ``chord - h - r <= distance <= chord + h``. The box is
at least 0.85 m from the link, so beyond it no error can hide a collision.

The network works in reference units (``ncedf.units``): a link of length L sees
its points divided by ``L / 2 m`` and its distance is multiplied back, so the
same recipe (box, noise, losses) trains a link of any size; for the paper's
link the unit is 1.

Weights are saved as flax msgpack bytes next to a JSON file of metadata
(architecture, encoding, robot spec, training settings, dataset hash,
validation metrics); ``load_model`` checks both.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import flax.linen as nn
import flax.serialization
import jax
import jax.numpy as jnp

from ncedf.data import BOX_MAX, BOX_MIN
from ncedf.geometry import to_bending_plane
from ncedf.precision import MATMUL
from ncedf.robot import (
    RobotSpec,
    arc_lengths_to_config,
    arc_sagitta,
    forward_kinematics,
    link_transform,
    points_in_link_frames,
)
from ncedf.units import unit

ENCODINGS = ("paper", "bending-plane")
OUTPUTS = ("distance", "signed-abs")
FORMAT_VERSION = 1
WEIGHTS_DIR = Path(__file__).parent / "weights"
DEFAULT_MODEL = WEIGHTS_DIR / "ncedf_4x16"


class ModelError(ValueError):
    """A weights file that is missing, corrupted or does not fit."""


@dataclasses.dataclass(frozen=True)
class ModelConfig:
    """Architecture of the link network.

    Attributes:
      layers: Dense layers including the output layer (paper Table I).
      width: units per hidden layer.
      encoding: "paper" or "bending-plane".
      output: "distance": the network output is the distance (the paper);
        "signed-abs": the network learns the signed distance, smooth across
        the surface, and the model reports its absolute value, so the kink of
        the unsigned distance at the surface is exact instead of rounded off.
    """

    layers: int = 4
    width: int = 16
    encoding: str = "bending-plane"
    output: str = "signed-abs"

    def __post_init__(self):
        if self.layers < 1:
            raise ValueError(f"layers must be >= 1, got {self.layers}")
        if self.width < 1:
            raise ValueError(f"width must be >= 1, got {self.width}")
        if self.encoding not in ENCODINGS:
            raise ValueError(f"encoding must be one of {ENCODINGS}, got {self.encoding!r}")
        if self.output not in OUTPUTS:
            raise ValueError(f"output must be one of {OUTPUTS}, got {self.output!r}")

    def head(self, raw: jnp.ndarray) -> jnp.ndarray:
        """The reported distance from the network's raw output."""
        return jnp.abs(raw) if self.output == "signed-abs" else raw

    @property
    def input_dim(self) -> int:
        return 5 if self.encoding == "paper" else 4


#: log1p(t) on [0, 1] as a degree-7 polynomial (least squares on Chebyshev nodes; largest error 2.3e-7).
_LOG1P = (2.2159764512252877e-07, 0.9999702572822571, -0.4993339478969574, 0.327511727809906,
          -0.22396689653396606, 0.13198965787887573, -0.053267478942871094, 0.010243828408420086)


def softplus(x: jnp.ndarray) -> jnp.ndarray:
    """``log(1 + e^x)`` within 2.3e-7 (plus float32 rounding): ``max(x, 0) + log1p(e^-|x|)`` with
    the ``log1p`` of ``t`` in (0, 1] a polynomial. On a CPU several times cheaper than XLA's
    ``logaddexp``, whose exponential and logarithm dominated the network's inference."""
    t = jnp.exp(jnp.minimum(x, -x))  # e^-|x|; its derivative at 0 is 0 (that of -|x| would be -1)
    poly = jnp.asarray(_LOG1P[-1], x.dtype)
    for c in _LOG1P[-2::-1]:
        poly = poly * t + jnp.asarray(c, x.dtype)
    return jnp.maximum(x, 0.0) + poly


class MLP(nn.Module):
    """Softplus MLP with He-uniform kernels; ``layers`` Dense layers, scalar output."""

    layers: int
    width: int

    @nn.compact
    def __call__(self, x: jnp.ndarray) -> jnp.ndarray:
        init = nn.initializers.he_uniform()
        for _ in range(self.layers - 1):
            x = softplus(nn.Dense(self.width, kernel_init=init, precision=MATMUL)(x))
        return nn.Dense(1, kernel_init=init, precision=MATMUL)(x)[..., 0]


def encode(points: jnp.ndarray, theta, phi, encoding: str) -> jnp.ndarray:
    """Network input for link-frame points, (P, 3) -> (P, 4 or 5)."""
    theta = jnp.broadcast_to(theta, points.shape[:-1])[..., None]
    if encoding == "paper":
        phi = jnp.broadcast_to(phi, points.shape[:-1])[..., None]
        return jnp.concatenate([theta, phi, points], axis=-1)
    return jnp.concatenate([theta, to_bending_plane(points, phi)], axis=-1)


def chord_bounds_from_end(points: jnp.ndarray, end: jnp.ndarray, sagitta, radius):
    """``chord_bounds`` given the link's end point ``end`` (3,) or (P, 3), sagitta and radius, scalars or (P,)."""
    t = jnp.clip(jnp.sum(points * end, axis=-1) / jnp.sum(end * end, axis=-1), 0.0, 1.0)
    to_chord = jnp.linalg.norm(points - t[..., None] * end, axis=-1)
    return to_chord - sagitta - radius, to_chord + sagitta


def chord_bounds(points: jnp.ndarray, theta, phi, spec: RobotSpec) -> tuple[jnp.ndarray, jnp.ndarray]:
    """Bounds of the distance from points outside a link to its surface, from its chord.

    Every backbone point lies within the sagitta ``h`` of the chord and every
    chord point within ``h`` of the backbone, so with ``c`` the distance to the
    chord: ``c - h - r <= distance <= c + h`` (the upper bound for points
    outside the link: the segment to the nearest backbone point crosses the surface).

    Args:
      points: (P, 3) link-frame points, m.  theta, phi: scalars, rad.
    Returns:
      lower (P,), upper (P,), m.
    """
    end = link_transform(theta, phi, spec)[:3, 3]
    return chord_bounds_from_end(points, end, arc_sagitta(theta, spec.length), spec.radius)


def init_params(key, config: ModelConfig):
    """Fresh parameters of the link network."""
    return MLP(config.layers, config.width).init(key, jnp.zeros((1, config.input_dim)))


def model_spec(spec: RobotSpec) -> RobotSpec:
    """The spec a model holds for a robot: one link, or every link of a tapered robot."""
    return RobotSpec(spec.n_links if spec.tapered else 1, **spec.link_geometry())


def stack_links(params: list):
    """Per-link parameter trees -> one tree with a leading link axis (a tapered robot's model)."""
    return jax.tree_util.tree_map(lambda *x: jnp.stack(x), *params)


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class NCEDF:
    """A trained N-CEDF. A JAX pytree: ``params`` are its leaves.

    Attributes:
      params: flax parameters of the link network; a tapered robot's stacked per link (leading axis M).
      config: its architecture (static).
      spec: the link geometry it was trained for (static; ``model_spec``: n_links is 1, or a tapered
        robot's M).
      domain: (box_min, box_max) of the training points, link frame, m (static).
      meta: metadata read from the weights file (static).
    """

    params: dict
    config: ModelConfig = dataclasses.field(metadata=dict(static=True))
    spec: RobotSpec = dataclasses.field(metadata=dict(static=True))
    domain: tuple = dataclasses.field(default=(BOX_MIN, BOX_MAX), metadata=dict(static=True))
    meta: tuple = dataclasses.field(default=(), metadata=dict(static=True))

    def apply(self, inputs: jnp.ndarray, link=None) -> jnp.ndarray:
        """The link distance from encoded inputs, (P, D) -> (P,) m.

        ``link`` (a tapered robot's model only): the link, a scalar, or one per input (P,); the
        latter runs every link's network on every input and keeps each input's own.
        """
        net = MLP(self.config.layers, self.config.width)
        if not self.spec.tapered:
            return self.config.head(net.apply(self.params, inputs))
        if jnp.ndim(link) == 0:
            return self.config.head(net.apply(jax.tree_util.tree_map(lambda x: jnp.asarray(x)[link], self.params), inputs))
        every = jax.vmap(net.apply, in_axes=(0, None))(self.params, inputs)  # (M, P)
        return self.config.head(jnp.take_along_axis(every, link[None], axis=0)[0])

    def link_distance(self, points: jnp.ndarray, theta, phi, link=None) -> jnp.ndarray:
        """Predicted distance from link-frame points to one link.

        Args:
          points: (P, 3) points in the link's base frame, m.
          theta, phi: scalars, rad.  link: the link's index (a tapered robot's model only).
        Returns:
          (P,) distances, m; beyond the domain, the bound from its nearest point.
        """
        end = link_transform(theta, phi, self.spec)[:3, 3]
        return self.local_distance(points, theta, phi, end, arc_sagitta(theta, self.spec.length), link)

    def local_distance(self, points: jnp.ndarray, theta, phi, end, sagitta, link=None) -> jnp.ndarray:
        """``link_distance`` with the link's end point and sagitta already known.

        Args:
          points: (P, 3) link-frame points, m.
          theta, phi: scalars or (P,), rad (one link configuration per point).
          end: (3,) or (P, 3) link end points in the link frame, m.  sagitta: scalar or (P,), m.
          link: scalar or (P,) link index (used by a tapered robot's model).
        Returns:
          (P,) the network's distance, clamped to the chord bounds outside the domain, m.
        """
        u = unit(self.spec)  # 1 for the paper's link: both scalings exact
        raw = u * self.apply(encode(points / u, theta, phi, self.config.encoding), link)
        outside = jnp.any((points < jnp.asarray(self.domain[0])) | (points > jnp.asarray(self.domain[1])), axis=-1)
        lower, upper = chord_bounds_from_end(points, end, sagitta, self.spec.radius_of(link))
        return jnp.where(outside, jnp.clip(raw, lower, upper), raw)

    def robot_link_distances(self, points: jnp.ndarray, arc: jnp.ndarray) -> jnp.ndarray:
        """Predicted distance from world points to every link, (M, P), m.

        Args:
          points: (P, 3) world points, m.  arc: (M, 3) arc lengths, m.
        """
        spec = RobotSpec(arc.shape[-2], **self.spec.link_geometry())  # a tapered model's M checked here
        local = points_in_link_frames(points, forward_kinematics(arc, spec))
        theta, phi = arc_lengths_to_config(arc, spec)
        return jax.vmap(self.link_distance)(local, theta, phi, jnp.arange(spec.n_links))

    def robot_distance(self, points: jnp.ndarray, arc: jnp.ndarray) -> jnp.ndarray:
        """Predicted distance from world points to the robot, (P,), m (eq. 6)."""
        return jnp.min(self.robot_link_distances(points, arc), axis=0)

    def links(self) -> list:
        """The model as one-link models: itself, or each link of a tapered robot's."""
        if not self.spec.tapered:
            return [self]
        return [dataclasses.replace(self, params=jax.tree_util.tree_map(lambda x: x[i], self.params),
                                    spec=self.spec.link(i)) for i in range(self.spec.n_links)]

    def rescaled(self, spec: RobotSpec) -> "NCEDF":
        """The same network for ``spec``, the link scaled by ``spec.length / self.spec.length``: its
        distances scale with the link (the network works in the link's units)."""
        factor = spec.length / self.spec.length
        domain = tuple(tuple(v * factor for v in corner) for corner in self.domain)
        return dataclasses.replace(self, spec=model_spec(spec), domain=domain)

    @property
    def metadata(self) -> dict:
        return dict(self.meta)


def save_model(path, params, config: ModelConfig, spec: RobotSpec, extra: dict,
               domain=(BOX_MIN, BOX_MAX)) -> tuple[Path, Path]:
    """Write ``<path>.msgpack`` (weights) and ``<path>.json`` (metadata).

    Args:
      path: file stem (a suffix, if any, is replaced).
      domain: (box_min, box_max) of the training points, link frame, m.
      extra: JSON-serialisable metadata (training settings, dataset hash, metrics).
    Returns:
      The two paths written.
    """
    stem = Path(path).with_suffix("")
    stem.parent.mkdir(parents=True, exist_ok=True)
    blob = flax.serialization.to_bytes(params)
    meta = {
        "format_version": FORMAT_VERSION,
        "architecture": dataclasses.asdict(config),
        "robot": spec.link_geometry(),
        "domain": {"box_min": list(domain[0]), "box_max": list(domain[1])},
        "n_parameters": int(sum(x.size for x in jax.tree_util.tree_leaves(params))),
        "weights_bytes": len(blob),
        **extra,
    }
    weights, meta_path = stem.with_suffix(".msgpack"), stem.with_suffix(".json")
    weights.write_bytes(blob)
    meta_path.write_text(json.dumps(meta, indent=2, sort_keys=True) + "\n")
    return weights, meta_path


def _freeze(value):
    if isinstance(value, dict):
        return tuple((k, _freeze(v)) for k, v in sorted(value.items()))
    if isinstance(value, list):
        return tuple(_freeze(v) for v in value)
    return value


def load_model(path=None, expect: ModelConfig | None = None) -> NCEDF:
    """Load a saved N-CEDF; with no path, the shipped default from ``ncedf/weights``.

    Args:
      path: ``.msgpack`` or ``.json`` file or their common stem.
      expect: if given, the architecture the caller needs; a different one is an error.
    Raises:
      ModelError: missing, corrupted or mismatched files (message names the file).
    """
    stem = Path(DEFAULT_MODEL if path is None else path)
    if stem.suffix in (".msgpack", ".json"):
        stem = stem.with_suffix("")
    weights, meta_path = stem.with_suffix(".msgpack"), stem.with_suffix(".json")
    for f in (weights, meta_path):
        if not f.is_file():
            raise ModelError(f"model file not found: {f}")
    try:
        meta = json.loads(meta_path.read_text())
        config = ModelConfig(**meta["architecture"])
        radius = meta["robot"].get("radius")
        spec = RobotSpec(n_links=len(radius) if isinstance(radius, list) else 1, **meta["robot"])
        domain = (tuple(meta["domain"]["box_min"]), tuple(meta["domain"]["box_max"]))
    except (ValueError, KeyError, TypeError) as exc:
        raise ModelError(f"corrupted model metadata {meta_path}: {exc}") from None
    if meta.get("format_version") != FORMAT_VERSION:
        raise ModelError(f"{meta_path}: unsupported format_version {meta.get('format_version')!r}")
    if expect is not None and expect != config:
        raise ModelError(f"{weights} holds a {config} network, expected {expect}")
    template = init_params(jax.random.PRNGKey(0), config)
    if spec.tapered:
        template = stack_links([template] * spec.n_links)
    try:
        params = flax.serialization.from_bytes(template, weights.read_bytes())
    except Exception as exc:  # msgpack raises many types on garbage
        raise ModelError(f"corrupted or mismatched weights {weights}: {type(exc).__name__}: {exc}") from None
    shapes = jax.tree_util.tree_map(jnp.shape, params)
    if shapes != jax.tree_util.tree_map(jnp.shape, template):
        raise ModelError(f"weights {weights} do not fit the architecture {config} in {meta_path}")
    leaves = jax.tree_util.tree_leaves(params)
    if not all(bool(jnp.all(jnp.isfinite(x))) for x in leaves):
        raise ModelError(f"weights {weights} contain NaN or inf")
    return NCEDF(params=params, config=config, spec=spec, domain=domain, meta=_freeze(meta))
