"""benchmarks/restoration_gate.py: the restorer against the render per pixel class on a finished
run's other cameras."""
from __future__ import annotations

import json

import numpy as np


def test_table_per_pixel_class(benchmark_script, tiny_run, tmp_path):
    gate_bench = benchmark_script("restoration_gate")
    run_dir, _ = tiny_run
    out = tmp_path / "gate.json"
    from fixer4d.restore.unobserved_fill import BACKGROUND_DEPTH_TOL

    assert gate_bench.main([str(run_dir), "--cameras-from", "tiny", "--stride", "4", "--out", str(out),
                            "--background-tols", f"0.02,{BACKGROUND_DEPTH_TOL}"]) == 0
    table = json.loads(out.read_text())["psnr_db"]
    assert set(table) == set(gate_bench.CLASSES)
    assert table["all"]["fraction"] == 1.0
    assert abs(table["unobserved"]["fraction"] + table["observed"]["fraction"] - 1.0) < 1e-9
    for k in gate_bench.IMAGES:
        assert np.isfinite(table["all"][k])
    # the study's column at the default tolerance is the pipeline's own fill
    for c in gate_bench.CLASSES:
        assert table[c][f"fill_tol{BACKGROUND_DEPTH_TOL:g}"] == table[c]["fill"]

    # two runs' files pair by their validation folder: the differences are image minus render
    again = tmp_path / "gate2.json"
    record = json.loads(out.read_text())
    record["run"] = "other"
    for row in record["psnr_db"].values():
        row["gate"] = None if row["gate"] is None else row["gate"] + 1.0
    again.write_text(json.dumps(record))
    summary = gate_bench.summarize([out, again])["tiny"]
    assert summary["runs"] == [str(run_dir), "other"]
    gain = summary["all"]["gate - render"]
    assert gain["n"] == 2 and abs(gain["values"][1] - gain["values"][0] - 1.0) < 1e-9
    assert summary["all"]["render"]["sd"] == 0.0
