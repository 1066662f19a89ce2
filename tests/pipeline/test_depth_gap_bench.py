"""benchmarks/depth_gap.py: where a finished run's stage-1 depth departs from its init's points."""
from __future__ import annotations

import json


def test_reports_each_group_of_cameras_and_leaves_the_run_alone(benchmark_script, tiny_run, tmp_path):
    bench = benchmark_script("depth_gap")
    run_dir, _ = tiny_run
    before = {p: p.stat().st_mtime_ns for p in run_dir.rglob("*")}
    out = tmp_path / "gap.json"
    assert bench.main([str(run_dir), "--novel", "4", "--out", str(out)]) == 0
    result = json.loads(out.read_text())
    for group in ("train", "novel"):
        g = result[group]
        assert g["pixels"] > 0 and 0.0 <= g["nearer"] <= 1.0 and 0.0 <= g["farther"] <= 1.0
        assert g["nearer"] + g["farther"] <= 1.0 and g["median_relative"] >= 0.0
    # the train views were fitted to depths close to the init's: most of their pixels agree
    assert result["train"]["nearer"] + result["train"]["farther"] < 0.5
    assert "held_out" not in result
    assert {p: p.stat().st_mtime_ns for p in run_dir.rglob("*")} == before


def test_a_run_without_a_dense_init_is_refused(benchmark_script, tmp_path, capsys):
    assert benchmark_script("depth_gap").main([str(tmp_path)]) == 2
    assert "run `fixer4d run` first" in capsys.readouterr().err
