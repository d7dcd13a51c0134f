"""Accuracy metrics of a learned distance against exact labels (paper Sec. VI-B).

MOE, the paper's mean over-estimation error, is ``mean(max(0, pred - true))``.
Beyond the paper: the 99.9th percentile of the over-estimation (the
safety-relevant tail), the worst error, the same metrics in the near field
(true distance below ``NEAR_FIELD`` m for the paper's 2 m link, in proportion for
another, where collisions are decided) and the
mean prediction on surface points (should be 0).
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

NEAR_FIELD = 0.5


def _errors(pred: np.ndarray, true: np.ndarray) -> dict:
    err = pred - true
    over = np.maximum(err, 0.0)
    return {
        "mae": float(np.mean(np.abs(err))),
        "rmse": float(np.sqrt(np.mean(err**2))),
        "moe": float(np.mean(over)),
        "over_p999": float(np.percentile(over, 99.9)),
        "max_error": float(np.max(np.abs(err))),
    }


def distance_metrics(pred, true, surface_pred=None, near_field: float = NEAR_FIELD) -> dict:
    """Metrics of predictions ``pred`` against labels ``true`` (same shape), m.

    Returns a flat dict: mae, rmse, moe, over_p999, max_error, the same with a
    ``near_`` prefix for true < ``near_field``, ``near_fraction`` and, when
    ``surface_pred`` (predictions on surface points) is given,
    ``surface_mean`` and ``surface_mae``.
    """
    pred = np.asarray(pred, dtype=np.float64).ravel()
    true = np.asarray(true, dtype=np.float64).ravel()
    out = _errors(pred, true)
    near = true < near_field
    out["near_fraction"] = float(near.mean())
    if near.any():
        out.update({f"near_{k}": v for k, v in _errors(pred[near], true[near]).items()})
    if surface_pred is not None:
        s = np.asarray(jnp.ravel(surface_pred), dtype=np.float64)
        out["surface_mean"] = float(s.mean())
        out["surface_mae"] = float(np.abs(s).mean())
    return out
