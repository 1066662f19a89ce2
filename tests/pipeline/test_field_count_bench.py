"""benchmarks/field_count.py: n of the quality runs' pooled fields merged, the spread and mean by n."""
from __future__ import annotations

import itertools

import numpy as np
import pytest


def test_few_subsets_are_all_taken_and_many_drawn_the_same_way_every_time(benchmark_script):
    bench = benchmark_script("field_count")
    names = [f"s{s}f{k}" for s in range(5) for k in range(2)]
    assert len(bench.subsets(names, 2, 45)) == 45
    drawn = bench.subsets(names, 3, 40)
    assert len(drawn) == len(set(drawn)) == 40 and drawn == bench.subsets(list(reversed(names)), 3, 40)
    assert all(list(m) == sorted(m) for m in drawn)


def test_the_gain_of_one_more_field_is_exact_when_fields_add(benchmark_script):
    """Scores that are the members' mean plus a per-size constant: the gain is the constant,
    with no jackknife error (leaving a field out moves both sizes alike), and the seed spread is
    that of a mean of n independent fields, s/√n, although the subsets share fields."""
    bench = benchmark_script("field_count")
    rng = np.random.default_rng(3)
    value = {f"f{i}": float(v) for i, v in enumerate(rng.normal(25.0, 0.3, 10))}
    pool = sorted(value)

    def scores(n, bonus):
        return {m: float(np.mean([value[x] for x in m])) + bonus for m in itertools.combinations(pool, n)}

    two, three = scores(2, 0.4), scores(3, 0.6)
    gain = bench.gain_over(three, two, pool)
    assert gain["gain_db"] == pytest.approx(0.2, abs=1e-12) and gain["se_db"] == pytest.approx(0.0, abs=1e-9)
    s = float(np.std(list(value.values()), ddof=1))
    one = bench.jackknife(scores(1, 0.0), pool)
    assert one["n"] == 10 and one["sd"] == pytest.approx(s)
    assert bench.jackknife(two, pool)["sd"] == pytest.approx(s / np.sqrt(2))
    assert bench.jackknife(three, pool)["sd"] == pytest.approx(s / np.sqrt(3))
    assert one["mean_se"] > 0 and one["sd_se"] > 0
    # the raw spread across overlapping subsets is smaller: (N - n) / N of the variance
    assert np.std(list(three.values())) == pytest.approx(s / np.sqrt(3) * np.sqrt(7 / 10))


def test_a_run_without_fields_is_named(benchmark_script, tmp_path):
    bench = benchmark_script("field_count")
    (tmp_path / "demo" / "seed0").mkdir(parents=True)
    with pytest.raises(SystemExit, match="seed0"):
        bench.pool_fields(tmp_path, "demo", [0])
