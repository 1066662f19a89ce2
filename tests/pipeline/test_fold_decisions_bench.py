"""benchmarks/fold_decisions.py: a check's decisions scored with stage 2 forced on the same runs."""
from __future__ import annotations

import json

import pytest


def _write(path, doc):
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(doc))


def test_refine_delivers_the_forced_gain_and_skip_the_stage1_model(benchmark_script, tmp_path):
    bench = benchmark_script("fold_decisions")
    forced, folds, quality = tmp_path / "forced", tmp_path / "folds", tmp_path / "quality"
    rows = {split: {"seeds": {"0": {"mvs": {"psnr": 20.0}, "views": {"psnr": 20.5}},
                              "1": {"mvs": {"psnr": 21.0}, "views": {"psnr": 20.8}},
                              "2": {"mvs": {"psnr": 22.0}, "views": {"psnr": 22.1}}}}  # seed 2: no fold
            for split in ("val", "test")}
    _write(forced / "forced_demo.json", rows)
    for seed, variant, own in ((0, "refine", "skip"), (1, "refine", "refine")):
        _write(folds / f"demo_seed{seed}.json", {"decision": variant, "gains": {"refine": {"gain_db": 0.2}},
                                                 "check_wall_s": 50.0, "run_check_s": 100.0, "run_stages_s": 400.0})
        for suffix in ("", "_val"):
            _write(quality / f"demo{suffix}_seed{seed}.json", {"self_check": {"decision": own}})
    out = tmp_path / "scored.json"
    assert bench.main(["--forced", str(forced), "--folds", str(folds), "--quality", str(quality),
                       "--out", str(out)]) == 0
    doc = json.loads(out.read_text())
    val = doc["sets"]["demo"]["val"]
    assert sorted(val["seeds"]) == ["0", "1"]
    assert val["variant_full_minus_mvs"]["values"] == pytest.approx([0.5, -0.2])
    assert val["own_full_minus_mvs"]["values"] == pytest.approx([0.0, -0.2])
    assert val["seeds"]["0"]["variant_share"] == pytest.approx(50.0 / 350.0)
    assert val["seeds"]["0"]["own_share"] == pytest.approx(0.25)
    assert doc["validation_all"]["variant"]["mean"] == pytest.approx(0.15)


def test_without_forced_files_it_says_so(benchmark_script, tmp_path, capsys):
    bench = benchmark_script("fold_decisions")
    assert bench.main(["--forced", str(tmp_path), "--folds", str(tmp_path), "--out", str(tmp_path / "x.json")]) == 2
    assert "forced_<SET>.json" in capsys.readouterr().out
