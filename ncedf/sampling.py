"""The sampling stage of MPPI: perturbations, zero-sum bounded rates, and the plan's update.

Each link's three chamber rates must sum to zero (the backbone is
inextensible). Two ways to make sampled rates so (``Sampling.kind``):

* ``"project"``: three rates are sampled, projected to zero sum and scaled per
  link so that no rate exceeds the bound (scaling keeps the zero sum;
  element-wise clipping would not);
* ``"release"`` (the authors' release): two free rates per link are sampled and
  clipped to the bound, the third is minus their sum (so it reaches twice the
  bound).

Noise is white over the horizon, or with ``smoothing`` beta > 0 a stationary
first-order low-pass sequence ``e_k = beta e_{k-1} + sqrt(1 - beta^2) n_k`` (the
same variance per step), so a rollout keeps its direction over the horizon.

The plan is updated with the weighted mean of the bounded samples, which lies
strictly inside the bound even when every good sample saturates it. With
``unclipped`` it is the weighted mean of the unbounded samples ``U + eps``, kept
within ``NOMINAL_SLACK`` bounds and bounded only when rolled out and executed,
so a plan at the bound stays there (the robot can move at its top rates).
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np

from ncedf.precision import MATMUL
from ncedf.validate import check_fields

#: Ways to sample zero-sum control rates (``Sampling.kind``).
KINDS = ("project", "release")
#: Bound of the unclipped plan (``Sampling.unclipped``), in units of the control bound.
NOMINAL_SLACK = 2.0


@dataclasses.dataclass(frozen=True)
class Sampling:
    """How rates are sampled and the plan updated (module docstring).

    Attributes:
      kind: "project" or "release".
      smoothing: beta in [0, 1) of the low-pass noise (0 = white).
      clip: each noise component clipped to +-clip, m/s (release: 0.5); None = no clip.
      unclipped: update the plan with the unbounded samples.
    """

    kind: str = "project"
    smoothing: float = 0.0
    clip: float | None = None
    unclipped: bool = False

    def __post_init__(self):
        check_fields(self, choices={"kind": KINDS}, unit={"smoothing": (0.0, 1.0)}, positive_or_none=("clip",),
                     flags=("unclipped",))


def project_controls(u: jnp.ndarray, bound: float) -> jnp.ndarray:
    """Make each link's three rates sum to zero, then scale so ``max |u| <= bound``.

    Args:
      u: (..., 3) rates per link, m/s.
    """
    u = u - jnp.mean(u, axis=-1, keepdims=True)
    peak = jnp.max(jnp.abs(u), axis=-1, keepdims=True)
    return u * jnp.minimum(1.0, bound / jnp.maximum(peak, 1e-30))


def release_controls(free: jnp.ndarray, bound: float) -> jnp.ndarray:
    """The release's zero-sum rates: two free rates clipped to ``+-bound``, the third minus their sum.

    Args:
      free: (..., 2) rates per link, m/s.
    Returns:
      (..., 3) rates, m/s (the third within ``+-2 bound``).
    """
    free = jnp.clip(free, -bound, bound)
    return jnp.concatenate([free, -jnp.sum(free, axis=-1, keepdims=True)], axis=-1)


def smoothing_matrix(horizon: int, beta: float) -> np.ndarray:
    """(H, H) lower-triangular L with ``e = L n`` the stationary low-pass sequence
    ``e_0 = n_0``, ``e_k = beta e_{k-1} + sqrt(1 - beta^2) n_k`` (unit variance per step for white n)."""
    k = np.arange(horizon)
    lag = k[:, None] - k[None, :]
    gain = np.where(k[None, :] == 0, 1.0, math.sqrt(1.0 - beta * beta))
    return np.where(lag >= 0, beta ** np.maximum(lag, 0) * gain, 0.0).astype(np.float32)


def sample_noise(sampling: Sampling, covariance: float, samples: int, key, dims: tuple[int, ...],
                 dtype) -> jnp.ndarray:
    """Perturbations (samples, H, M, 3) m/s: Gaussian with variance ``covariance``, low-pass over the
    horizon if ``smoothing`` > 0, clipped to ``clip``; with release sampling the third rate of each
    link carries no noise (it is derived)."""
    eps = math.sqrt(covariance) * jax.random.normal(key, (samples,) + dims, dtype)
    if sampling.smoothing > 0:
        eps = jnp.einsum("ts,nsmc->ntmc", smoothing_matrix(dims[0], sampling.smoothing), eps, precision=MATMUL)
    if sampling.clip is not None:
        eps = jnp.clip(eps, -sampling.clip, sampling.clip)
    if sampling.kind == "release":
        eps = eps.at[..., 2].set(0.0)
    return eps


def bounded_controls(sampling: Sampling, bound: float, raw: jnp.ndarray) -> jnp.ndarray:
    """Zero-sum rates within ``bound`` (..., M, 3) m/s from unbounded ones (with release sampling
    the third raw rate is ignored)."""
    if sampling.kind == "release":
        return release_controls(raw[..., :2], bound)
    return project_controls(raw, bound)


def update_plan(sampling: Sampling, bound: float, alpha: float, nominal, perturbed, bounded, weights):
    """The plan after the update: ``(1 - alpha) U + alpha sum_j w_j v_j`` with ``v`` the bounded
    samples, or with ``unclipped`` the unbounded ones (then kept within ``NOMINAL_SLACK`` bounds).

    Args:
      nominal: (H, M, 3) m/s.  perturbed, bounded: (N, H, M, 3) m/s.  weights: (N,) summing to 1.
    Returns:
      (raw, updated): the plan kept as the next warm start and its bounded form, (H, M, 3) each.
    """
    if sampling.unclipped:
        raw = (1.0 - alpha) * nominal + alpha * jnp.einsum("n,nhmc->hmc", weights, perturbed, precision=MATMUL)
        raw = jnp.clip(raw, -NOMINAL_SLACK * bound, NOMINAL_SLACK * bound)
        return raw, bounded_controls(sampling, bound, raw)
    raw = (1.0 - alpha) * nominal + alpha * jnp.einsum("n,nhmc->hmc", weights, bounded, precision=MATMUL)
    return raw, raw
