"""The temperature stage of MPPI: the lambda of the weights ``w = exp(-C~ / lambda)``.

The costs ``C~`` are normalised to [0, 1] over the samples, so lambda is
dimensionless. The paper fixes it (:class:`Fixed`, 0.02). At the release's
noise that leaves about one sample with weight, so the update executes one
noisy rollout; :class:`EffectiveSampleSize` instead picks, per step, the
smallest lambda of ``TEMPERATURE_GRID`` whose weights have an effective sample
size ``1 / sum w^2`` of at least ``target * N`` (and ``MIN_ESS``), so the update
averages several samples.

A robot that makes no progress for a while (the core's stall count,
``ncedf.mppi.MPPIState.stalled``) is usually held by a balance of goal and collision
costs that a smooth average keeps; :class:`StallEscape` then asks for a
smaller effective sample size (sharper weights, larger steps) until the goal
distance falls again. The phase of fast progress, where the robot passes
obstacles, keeps the smooth average.
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np

from ncedf.validate import check_fields

#: Candidate temperatures of :class:`EffectiveSampleSize` (on costs normalised to [0, 1]).
TEMPERATURE_GRID = tuple(float(x) for x in np.logspace(-4, 1, 64))
#: Least effective sample size asked for (few rollouts would otherwise execute one noisy sample), samples.
MIN_ESS = 4.0


@dataclasses.dataclass(frozen=True)
class Fixed:
    """A fixed lambda (the paper's 0.02)."""

    value: float = 0.02

    def __post_init__(self):
        check_fields(self, positive=("value",))

    def choose(self, norm: jnp.ndarray, stalled: jnp.ndarray) -> jnp.ndarray:
        """lambda for the normalised costs ``norm`` (N,) and the stall count (scalar int)."""
        return jnp.asarray(self.value, norm.dtype)


@dataclasses.dataclass(frozen=True)
class StallEscape:
    """After more than ``after`` steps without progress, an effective sample size of ``target`` N."""

    after: int = 30
    target: float = 0.005

    def __post_init__(self):
        check_fields(self, integers=("after",), fractions=("target",))


@dataclasses.dataclass(frozen=True)
class EffectiveSampleSize:
    """lambda chosen per step for an effective sample size of at least ``target`` N (in (0, 1]),
    with an optional :class:`StallEscape`."""

    target: float = 0.02
    escape: StallEscape | None = None

    def __post_init__(self):
        check_fields(self, fractions=("target",))
        if self.escape is not None and not isinstance(self.escape, StallEscape):
            raise ValueError(f"EffectiveSampleSize.escape must be a StallEscape or None, got {self.escape!r}")

    def choose(self, norm: jnp.ndarray, stalled: jnp.ndarray) -> jnp.ndarray:
        """lambda for the normalised costs ``norm`` (N,) and the stall count (scalar int)."""
        target = self.target
        if self.escape is not None:
            target = jnp.where(stalled > self.escape.after, self.escape.target, self.target)
        return temperature_for_ess(norm, target)


def temperature_for_ess(norm: jnp.ndarray, target) -> jnp.ndarray:
    """The smallest lambda of ``TEMPERATURE_GRID`` whose weights ``exp(-norm / lambda)`` have an
    effective sample size >= ``max(target * N, MIN_ESS)`` (at most N; the largest lambda if none has).

    Args:
      norm: (N,) costs normalised to [0, 1].  target: scalar in (0, 1] (may be traced).
    """
    grid = jnp.asarray(TEMPERATURE_GRID, norm.dtype)
    w = jnp.exp(-norm[None] / grid[:, None])  # (G, N); the minimum keeps weight 1
    ess = jnp.sum(w, axis=1) ** 2 / jnp.sum(w * w, axis=1)
    n = norm.shape[0]
    ok = ess >= jnp.minimum(jnp.maximum(target * n, MIN_ESS), n)
    return jnp.where(jnp.any(ok), grid[jnp.argmax(ok)], grid[-1])
