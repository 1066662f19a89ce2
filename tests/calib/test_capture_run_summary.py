"""benchmarks/capture_run.py --summarize: the mean over the seeds' result files, and the bar on it."""
from __future__ import annotations

import json

import pytest


def _seed_file(path, seed, a_full, b_full, finished=True):
    rec = {"seed": seed, "commit": "abc1234"}
    if finished:
        rec["summary"] = {"A": {"STGS w/ MVS": a_full - 0.1, "Full": a_full},
                          "B": {"STGS w/ MVS": b_full - 0.1, "Full": b_full}}
        rec["full_A_minus_B_db"] = a_full - b_full
    path.write_text(json.dumps(rec))
    return path


def test_mean_over_finished_seeds_and_the_bar(benchmark_script, tmp_path):
    cap = benchmark_script("capture_run")
    files = [_seed_file(tmp_path / "s0.json", None, 25.9, 25.2),
             _seed_file(tmp_path / "s1.json", 1, 25.5, 25.4),
             _seed_file(tmp_path / "s2.json", 2, 24.6, 25.0),
             _seed_file(tmp_path / "s3.json", 3, 10.0, 25.0, finished=False)]   # a killed run: not counted
    out = cap.summarize(files)
    assert [s["seed"] for s in out["seeds"]] == [None, 1, 2]
    assert out["mean"]["A"]["Full"] == pytest.approx(25.333333, abs=1e-5)
    assert out["mean"]["B"]["Full"] == pytest.approx(25.2, abs=1e-9)
    assert out["full_A_minus_B_db"] == pytest.approx(0.133333, abs=1e-5)
    assert out["spread_full_A_minus_B_db"] == pytest.approx([-0.4, 0.7])
    assert out["done_when"] == {"threshold_db": cap.DONE_WHEN_DB, "met": True}

    far = cap.summarize([_seed_file(tmp_path / "f.json", 0, 26.0, 25.0)])
    assert far["done_when"]["met"] is False


def test_no_finished_run_is_refused(benchmark_script, tmp_path):
    cap = benchmark_script("capture_run")
    with pytest.raises(SystemExit, match="no finished capture runs"):
        cap.summarize([_seed_file(tmp_path / "k.json", 0, 1.0, 1.0, finished=False)])
