"""benchmarks/demo_reproduction.py: make run's rows against the results table's demo seed 0."""
from __future__ import annotations

import pytest


def test_rows_are_compared_digit_for_digit(benchmark_script):
    bench = benchmark_script("demo_reproduction")
    reference = [{"method": "STGS w/ MVS", "psnr": 24.301}, {"method": "Full", "psnr": 24.301}]
    same = bench.compare([dict(r) for r in reference], reference)
    assert all(r["identical"] for r in same.values())
    off = bench.compare([{"method": "STGS w/ MVS", "psnr": 24.301}, {"method": "Full", "psnr": 24.3010000001}], reference)
    assert off["STGS w/ MVS"]["identical"] and not off["Full"]["identical"]
    missing = bench.compare([{"method": "STGS w/ MVS", "psnr": 24.301}], reference)
    assert missing["Full"] == {"psnr": None, "reference_psnr": 24.301, "identical": False}


def test_a_folder_holding_a_run_is_refused(benchmark_script, tmp_path):
    bench = benchmark_script("demo_reproduction")
    (tmp_path / "config.json").write_text("{}")
    with pytest.raises(SystemExit):
        bench.main(["--run", str(tmp_path), "--out", str(tmp_path / "out.json")])
