"""benchmarks/restoration_gate.py: the restorer against the render per pixel class on a finished
run's other cameras."""
from __future__ import annotations

import json

import numpy as np


def test_table_per_pixel_class(benchmark_script, tiny_run, tmp_path):
    gate_bench = benchmark_script("restoration_gate")
    run_dir, _ = tiny_run
    out = tmp_path / "gate.json"
    assert gate_bench.main([str(run_dir), "--cameras-from", "tiny", "--stride", "4", "--out", str(out)]) == 0
    table = json.loads(out.read_text())["psnr_db"]
    assert set(table) == set(gate_bench.CLASSES)
    assert table["all"]["fraction"] == 1.0
    assert abs(table["unobserved"]["fraction"] + table["observed"]["fraction"] - 1.0) < 1e-9
    for k in gate_bench.IMAGES:
        assert np.isfinite(table["all"][k])

