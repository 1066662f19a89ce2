"""benchmarks/training_device.py on the tiny scene: one row per device asked for, its stage-1
seconds and held-out PSNR those of the run folder it trained, the machine and commit recorded."""
from __future__ import annotations

import json


def test_one_row_per_device_from_its_own_run(benchmark_script, tmp_path):
    bench = benchmark_script("training_device")
    out = tmp_path / "devices.json"
    assert bench.main(["tiny", "--devices", "cpu", "--set", "training.iterations=6", "--runs", str(tmp_path / "runs"),
                       "--out", str(out)]) == 0
    result = json.loads(out.read_text())
    (row,) = result["rows"]
    report = json.loads((tmp_path / "runs" / "cpu" / "report.json").read_text())
    mvs = next(r for r in report["rows"] if r["method"] == "STGS w/ MVS")
    assert row["device"] == "cpu" and row["iterations"] == 6 and row["psnr"] == mvs["psnr"]
    assert row["stage1_seconds"] == round(report["stage_seconds"]["stage1"], 2) and row["gaussians"] > 0
    assert result["sets"] == {"training.iterations": 6} and "machine" in result and "commit" in result
