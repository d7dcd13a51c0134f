"""Small statistics for the tables: Wilson score intervals for rates, mean and std of times (also pooled
from per-run counts, means and stds)."""

from __future__ import annotations

import math

import numpy as np

#: Normal quantile of a two-sided 95% interval.
Z95 = 1.959963984540054


def wilson(successes: int, n: int, z: float = Z95) -> tuple[float, float]:
    """Wilson score interval of a binomial rate ``successes / n``: (low, high); (nan, nan) when n = 0."""
    if n == 0:
        return math.nan, math.nan
    p = successes / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z / (1 + z * z / n) * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n))
    return max(0.0, centre - half), min(1.0, centre + half)


def mean_std(values) -> tuple[float, float, int]:
    """Mean, sample-free (population) std and count of the finite values; NaNs when there are none."""
    v = np.asarray(values, dtype=np.float64)
    v = v[np.isfinite(v)]
    if not v.size:
        return math.nan, math.nan, 0
    return float(v.mean()), float(v.std()), int(v.size)


def pooled_mean_std(counts, means, stds) -> tuple[float, float, int]:
    """Mean, population std and count of the union of groups given each group's count, mean and
    population std (groups with count 0 or NaN count are ignored); NaNs when nothing is left.

    Exact: N = sum n_i, mean = sum n_i m_i / N, var = sum n_i (s_i^2 + (m_i - mean)^2) / N.
    """
    n = np.nan_to_num(np.asarray(counts, dtype=np.float64))
    keep = n > 0
    n, m, s = n[keep], np.asarray(means, dtype=np.float64)[keep], np.asarray(stds, dtype=np.float64)[keep]
    total = n.sum()
    if not total:
        return math.nan, math.nan, 0
    mean = float((n * m).sum() / total)
    var = float((n * (s * s + (m - mean) ** 2)).sum() / total)
    return mean, math.sqrt(var), int(total)
