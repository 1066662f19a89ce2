"""benchmarks/co_fields.py: both fields from a finished run's init, field A paired with the run's row."""
from __future__ import annotations

import json

import pytest


@pytest.fixture(scope="module")
def bench(benchmark_script):
    return benchmark_script("co_fields")


def test_field_a_without_co_pruning_is_the_runs_stage1_and_the_weights_pair_on_it(bench, one_field_run, tmp_path):
    """With no co-pruning step the twin trains beside field A without touching it: field A scores
    the run's "STGS w/ MVS" row exactly; the visibility weight's row is the run's "Restoration
    (init)" row, and the summary pairs field A with the baseline file (a one-field run: co_fields
    trains its twin beside one field)."""
    run_dir, report = one_field_run
    rows = {r["method"]: r for r in report["rows"]}
    baseline = tmp_path / "baseline.json"
    baseline.write_text(json.dumps({"rows": report["rows"]}))
    out, fields = tmp_path / "run.json", tmp_path / "fields"
    assert bench.main(["run", str(run_dir), "--set", "co_fields.prune_every=1000", "--baseline", str(baseline),
                       "--out", str(out), "--save-fields", str(fields)]) == 0
    doc = json.loads(out.read_text())
    assert doc["co_prune"] == [] and doc["field_a"]["psnr"] == pytest.approx(rows["STGS w/ MVS"]["psnr"], abs=1e-6)
    assert doc["gain_db"] == pytest.approx(0.0, abs=1e-6)
    assert doc["field_b"]["psnr"] != doc["field_a"]["psnr"]  # another seed
    weights = tmp_path / "weights.json"
    assert bench.main(["weights", str(run_dir), "--fields", str(fields), "--out", str(weights)]) == 0
    w = json.loads(weights.read_text())["rows"]
    assert w["visibility"]["psnr"] == pytest.approx(rows["Restoration (init)"]["psnr"], abs=1e-6)
    assert set(w) == {"visibility", "undetermined", "max"}
    summary = tmp_path / "summary.json"
    assert bench.main(["summary", str(out), "--out", str(summary)]) == 0
    (entry,) = json.loads(summary.read_text()).values()
    assert entry["seeds"] == [doc["seed"]] and entry["gain_db"]["mean"] == pytest.approx(0.0, abs=1e-6)
