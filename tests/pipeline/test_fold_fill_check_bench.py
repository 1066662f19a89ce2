"""benchmarks/fold_fill_check.py: the learned restorer's held-back fold scored per pixel class,
from a finished run's train cameras only, without writing into the run."""
from __future__ import annotations

import json

import numpy as np
import pytest

from pipeline_tiny import run_spied, tiny_config

# The tiny pipeline with the smallest learned restorer, its Restoration rows and nothing after.
LEARNED = {"restorer.kind": "learned", "restorer.learned.loo_iterations": 10, "restorer.learned.pair_frames": 2,
           "restorer.learned.steps": 4, "restorer.learned.batch": 2, "restorer.learned.crop": 16,
           "stage2.rounds": 0, "self_check.enabled": False, "eval.restoration_rows": True}


def _tree(path):
    return {p.relative_to(path): p.stat().st_mtime_ns for p in sorted(path.rglob("*")) if p.is_file()}


def test_fold_table_from_train_cameras_only(benchmark_script, stage_cache, tmp_path):
    bench = benchmark_script("fold_fill_check")
    run_dir = tmp_path / "run"
    _, spy = run_spied(tiny_config(**LEARNED), run_dir, stage_cache)
    before = _tree(run_dir)
    out = tmp_path / "fold.json"
    assert bench.main([str(run_dir), "--out", str(out)]) == 0
    assert _tree(run_dir) == before  # the run folder is only read
    record = json.loads(out.read_text())
    held = json.loads((run_dir / "restorer" / "validation.json").read_text())["held_out_fold_camera"]
    assert record["held_back_train_camera"] == held and held in spy.train_ids
    table = record["psnr_db"]
    assert set(table) == set(bench.CLASSES) and table["all"]["fraction"] == 1.0
    assert table["unobserved"]["fraction"] + table["observed"]["fraction"] == pytest.approx(1.0)
    for k in bench.IMAGES:
        assert np.isfinite(table["all"][k])
    # the fill leaves observed pixels as rendered
    if table["observed"]["fraction"] > 0:
        assert table["observed"]["fill"] == pytest.approx(table["observed"]["render"], abs=1e-6)


def test_refuses_a_run_without_the_learned_restorer(benchmark_script, tiny_run):
    bench = benchmark_script("fold_fill_check")
    with pytest.raises(Exception, match="learned restorer"):
        bench.main([str(tiny_run[0])])
