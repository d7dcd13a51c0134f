"""analysis.stats.pooled_mean_std against the mean and std of the concatenated values."""

from __future__ import annotations

import math

import numpy as np
import pytest

from analysis.stats import mean_std, pooled_mean_std


def test_pooled_equals_the_statistics_of_all_values():
    rng = np.random.default_rng(0)
    groups = [rng.lognormal(m, s, n) for m, s, n in ((3.0, 0.5, 300), (1.0, 0.1, 7), (5.0, 2.0, 1), (0.0, 1.0, 50))]
    stats = [mean_std(g) for g in groups] + [(math.nan, math.nan, 0)]  # a run without a value
    counts, means, stds = ([s[i] for s in stats] for i in (2, 0, 1))
    mean, std, n = pooled_mean_std(counts, means, stds)
    values = np.concatenate(groups)
    assert n == values.size
    assert mean == pytest.approx(values.mean(), rel=1e-13)
    assert std == pytest.approx(values.std(), rel=1e-12)


def test_nothing_to_pool():
    mean, std, n = pooled_mean_std([0, math.nan], [math.nan, math.nan], [math.nan, math.nan])
    assert math.isnan(mean) and math.isnan(std) and n == 0
