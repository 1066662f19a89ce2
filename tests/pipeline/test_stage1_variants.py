"""benchmarks/stage1_variants.py: stage 1 alone from a finished run's init under config variants."""
from __future__ import annotations

import json

import numpy as np
import pytest


@pytest.fixture(scope="module")
def variants(benchmark_script):
    return benchmark_script("stage1_variants")


def test_overrides_apply_on_the_run_config(variants, tiny_run):
    from fixer4d.pipeline.run_folder import read_run_config

    run_dir, _ = tiny_run
    base = read_run_config(run_dir)
    cfg = variants.variant_config(run_dir, ["training.prune_world_scale=0.1", "training.seed=3"])
    assert cfg.training.prune_world_scale == 0.1 and cfg.training.seed == 3
    assert cfg.training.iterations == base.training.iterations and cfg.scene == base.scene
    # a new iteration count brings its own schedule, as `fixer4d run --iterations` would
    from fixer4d.train.config import TrainingConfig

    longer = variants.variant_config(run_dir, [f"training.iterations={4 * base.training.iterations}"])
    derived = TrainingConfig.for_iterations(4 * base.training.iterations)
    assert longer.training.densify_until == derived.densify_until == 2 * base.training.iterations
    assert longer.training.opacity_reset_every == derived.opacity_reset_every


def test_reproduces_the_runs_stage1_row_and_leaves_the_run_alone(variants, one_field_run, tmp_path):
    """With no override the variant is a one-field run's own stage 1: the same held-out PSNR as
    the run's "STGS w/ MVS" row (training is deterministic), and RUN is only read."""
    run_dir, report = one_field_run
    before = {p: p.stat().st_mtime_ns for p in run_dir.rglob("*")}
    out = tmp_path / "variant.json"
    assert variants.main([str(run_dir), "--out", str(out)]) == 0
    doc = json.loads(out.read_text())
    row = next(r for r in report["rows"] if r["method"] == "STGS w/ MVS")
    assert doc["psnr"] == pytest.approx(row["psnr"], abs=1e-6)
    assert np.isfinite(doc["train_view_psnr"]) and doc["gaussians"] > 0
    assert {p: p.stat().st_mtime_ns for p in run_dir.rglob("*")} == before


def test_tail_averages_leave_the_last_iterate_as_it_was(variants, one_field_run, tmp_path):
    """--average-from scores the mean of the iterates after a step beside the last iterate, whose
    figures stay those of plain training (the averages are scored on a copy of the state)."""
    run_dir, report = one_field_run
    out = tmp_path / "averaged.json"
    assert variants.main([str(run_dir), "--average-from", "20", "--average-from", "30", "--out", str(out)]) == 0
    doc = json.loads(out.read_text())
    row = next(r for r in report["rows"] if r["method"] == "STGS w/ MVS")
    assert doc["psnr"] == pytest.approx(row["psnr"], abs=1e-6)
    assert doc["averaged"]["20"]["iterates"] == 2 and doc["averaged"]["30"]["iterates"] == 1
    assert doc["averaged"]["30"]["psnr"] == pytest.approx(doc["psnr"], abs=1e-6)  # one iterate: the last one
    assert np.isfinite(doc["averaged"]["20"]["psnr"])


def test_a_run_without_dense_init_is_refused(variants, tmp_path, capsys):
    assert variants.main([str(tmp_path)]) == 2
    assert "no decomposed dense init" in capsys.readouterr().err
