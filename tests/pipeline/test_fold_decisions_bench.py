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


def test_without_forced_runs_only_the_seeds_whose_full_is_known_are_scored(benchmark_script, tmp_path):
    bench = benchmark_script("fold_decisions")
    folds, own_folds, quality = tmp_path / "folds", tmp_path / "own", tmp_path / "quality"

    def fold(decision, cpu):
        return {"decision": decision, "gains": {"refine": {"gain_db": -0.3}}, "check_wall_s": cpu, "check_cpu_s": cpu}

    def record(decision, mvs, full):
        return {"self_check": {"decision": decision},
                "rows": [{"method": "STGS w/ MVS", "psnr": mvs}, {"method": "Full", "psnr": full}]}

    # seed 0: both skip; seed 1: the run refined (+0.2), the variant skips; seed 2: the run skipped,
    # the variant refines (stage 2's gain unknown); seed 3: a config-only folder, both checks as folds
    for seed, decision in ((0, "skip"), (1, "skip"), (2, "refine"), (3, "skip")):
        _write(folds / f"demo_seed{seed}.json", fold(decision, 50.0))
    for seed, own, mvs, full in ((0, "skip", 20.0, 20.0), (1, "refine", 20.0, 20.2), (2, "skip", 21.0, 21.0)):
        for suffix in ("", "_val"):
            _write(quality / f"demo{suffix}_seed{seed}.json", record(own, mvs, full))
    _write(own_folds / "demo_seed3.json", fold("skip", 200.0))
    out = tmp_path / "scored.json"
    assert bench.main(["--folds", str(folds), "--own-folds", str(own_folds), "--quality", str(tmp_path / "none"),
                       "--quality", str(quality), "--out", str(out)]) == 0
    val = json.loads(out.read_text())["sets"]["demo"]["val"]
    assert sorted(val["seeds"]) == ["0", "1", "3"] and val["unscored"] == ["2"]
    assert val["own_full_minus_mvs"]["values"] == pytest.approx([0.0, 0.2, 0.0])
    assert val["variant_minus_own"]["values"] == pytest.approx([0.0, -0.2, 0.0])
    assert val["seeds"]["3"]["variant_over_own_cpu"] == pytest.approx(0.25)
