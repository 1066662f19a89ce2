"""benchmarks/self_check_folds.py: the self-check alone on a finished run under other settings."""
from __future__ import annotations

import json


def test_reproduces_the_runs_check_and_leaves_the_run_alone(benchmark_script, tiny_run, tmp_path):
    """With no override it is the run's own check (same decision and figures: training is
    deterministic); RUN is only read; an override reaches the check."""
    bench = benchmark_script("self_check_folds")
    run_dir, report = tiny_run
    before = {p: p.stat().st_mtime_ns for p in run_dir.rglob("*")}
    out = tmp_path / "check.json"
    assert bench.main([str(run_dir), "--out", str(out)]) == 0
    doc = json.loads(out.read_text())
    own = report["self_check"]
    assert doc["decision"] == own["decision"] == doc["run_decision"]
    assert doc["psnr"] == own["psnr"] and doc["gain_unit"] == "frame"
    assert doc["check_wall_s"] > 0 and doc["run_check_s"] > 0
    assert {p: p.stat().st_mtime_ns for p in run_dir.rglob("*")} == before
    assert bench.main([str(run_dir), "--set", "self_check.cameras=2", "--out", str(out)]) == 0
    two = json.loads(out.read_text())
    assert two["gain_unit"] == "fold" and len(two["folds"]) == 2 and two["folds"][0]["psnr"] == own["psnr"]
