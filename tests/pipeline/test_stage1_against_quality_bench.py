"""benchmarks/stage1_against_quality.py: stage-1 option runs paired with the quality files of their seeds."""
from __future__ import annotations

import json

import pytest

from fixer4d.pipeline.config import RunConfig, SceneConfig
from fixer4d.train.config import TrainingConfig


def _write(path, doc):
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(doc))


def _rows(psnr, lpips):
    return [{"method": "STGS w/ MVS", "psnr": psnr, "lpips": lpips}, {"method": "Full", "psnr": 0.0}]


def test_each_run_is_paired_with_its_seed_and_the_option_named(benchmark_script, tmp_path):
    bench = benchmark_script("stage1_against_quality")
    quality = tmp_path / "quality"
    runs = []
    for seed, (base, option) in enumerate(((25.0, 25.3), (24.0, 24.1))):
        base_config = RunConfig(scene=SceneConfig("demo"), training=TrainingConfig(seed=seed)).to_dict()
        del base_config["training"]["scale_ratio_weight"]  # a quality file older than the option
        for suffix, shift in (("", 0.0), ("_val", 1.0)):
            _write(quality / f"demo{suffix}_seed{seed}.json",
                   {"config": {"config": base_config}, "rows": _rows(base + shift, 0.10)})
        config = RunConfig(scene=SceneConfig("demo"), training=TrainingConfig(seed=seed, scale_ratio_weight=0.01),
                           baseline_sparse=False).to_dict()
        run = tmp_path / f"run{seed}"
        _write(run / "config.json", {"config": config})
        _write(run / "report.json", {"rows": _rows(option, 0.09)})
        _write(run / "heldout" / "demo_val" / "report.json", {"rows": _rows(option + 1.5, 0.08)})
        runs.append(str(run))
    out = tmp_path / "scored.json"
    assert bench.main([*runs, "--quality", str(quality), "--out", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert doc["runs"][0]["option"] == ["training.scale_ratio_weight: 0.0 -> 0.01"]  # the stage-1-only switches aside
    summary = doc["summary"]["training.scale_ratio_weight: 0.0 -> 0.01"]["demo"]
    assert summary["seeds"] == [0, 1]
    assert summary["test"]["psnr"]["values"] == pytest.approx([0.3, 0.1])
    assert summary["validation"]["psnr"]["values"] == pytest.approx([0.8, 0.6])
    assert summary["validation"]["lpips"]["mean"] == pytest.approx(-0.02)
