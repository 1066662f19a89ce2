"""benchmarks/seed_spread_where.py: quantile bins and the split of the seeds' error variance."""
from __future__ import annotations

import numpy as np
import pytest


def test_bins_cut_each_row_at_its_own_quantiles(benchmark_script):
    bench = benchmark_script("seed_spread_where")
    d = np.stack([np.arange(100.0), np.arange(100.0)[::-1] * 3])
    bins = bench.quantile_bins(d, (0.5, 0.9))
    assert bins.shape == d.shape
    assert [int((bins[0] == k).sum()) for k in range(3)] == [50, 40, 10]
    assert [int((bins[1] == k).sum()) for k in range(3)] == [50, 40, 10]
    assert bins[0, 99] == 2 and bins[1, 0] == 2 and bins[1, 99] == 0


def test_the_shares_sum_to_one_and_find_the_pixels_that_moved(benchmark_script):
    bench = benchmark_script("seed_spread_where")
    rng = np.random.default_rng(0)
    seeds, pixels = 8, 400
    error = np.full((seeds, pixels), 0.01)
    error[:, :40] += rng.uniform(0.0, 0.2, size=(seeds, 1))  # the first tenth moves with the seed
    error += rng.normal(0.0, 1e-6, size=error.shape)  # and every pixel a hair
    groups = np.broadcast_to((np.arange(pixels) >= 40).astype(int), error.shape)
    rows = bench.variance_shares(error, groups, 2)
    assert sum(r["variance"] for r in rows) == pytest.approx(1.0)
    assert sum(r["error"] for r in rows) == pytest.approx(1.0)
    assert rows[0]["pixels"] == pytest.approx(0.1)
    assert rows[0]["variance"] > 0.99 and abs(rows[1]["variance"]) < 0.01


def test_a_variance_needs_two_seeds_and_a_moving_error(benchmark_script):
    bench = benchmark_script("seed_spread_where")
    with pytest.raises(ValueError, match="two seeds"):
        bench.variance_shares(np.ones((1, 4)), np.zeros((1, 4), int), 1)
    with pytest.raises(ValueError, match="same for every seed"):
        bench.variance_shares(np.ones((3, 4)), np.zeros((3, 4), int), 1)
    with pytest.raises(ValueError, match="same \\(S, P\\)"):
        bench.variance_shares(np.ones((3, 4)), np.zeros((3, 5), int), 1)
