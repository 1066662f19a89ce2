"""Published result tables are generated from the committed result files (docs/results/*.json)."""
from __future__ import annotations

import json
from pathlib import Path

REPO_ROOT = Path(__file__).resolve().parents[1]


def test_the_published_table_matches_the_committed_result_files(benchmark_script):
    tables = benchmark_script("results_table")
    text = (REPO_ROOT / "docs" / "results.md").read_text()
    assert tables.block() in text, "docs/results.md: run `python benchmarks/results_table.py write`"


def test_every_result_file_says_how_it_was_made():
    files = sorted((REPO_ROOT / "docs" / "results").glob("*.json"))
    assert files
    for path in files:
        data = json.loads(path.read_text())
        assert data["command"] and data["commit"] and data["date"] and data["rows"], path.name
        assert data["machine"]["cores"] >= 1 and len(data["machine"]["load_average_at_record"]) == 3


def test_a_run_folder_names_the_code_that_made_it(tmp_path):
    """config.json carries the source commit, and a record takes it over the checkout's."""
    from fixer4d.pipeline.config import resolve
    from fixer4d.pipeline.run_folder import RunFolder, source_commit

    folder = RunFolder.create(tmp_path / "run", resolve("tiny"))
    stamp = json.loads((folder.path / "config.json").read_text())["source_commit"]
    assert stamp == source_commit()
    if stamp is not None:  # a git checkout: a short hash, maybe with "+changes"
        assert len(stamp.split("+")[0]) >= 7


def test_a_record_of_other_cameras_keeps_the_runs_seconds(benchmark_script, tmp_path, monkeypatch):
    """RUN/heldout/<folder>/ has no training of its own: its record takes the run's seconds per stage."""
    tables = benchmark_script("results_table")
    monkeypatch.setattr(tables, "RESULTS", tmp_path / "results")
    run = tmp_path / "run"
    (run / "heldout" / "val").mkdir(parents=True)
    (run / "config.json").write_text(json.dumps({"source_commit": "abc1234"}))
    (run / "report.json").write_text(json.dumps({"rows": [{"method": "m", "psnr": 1.0}], "stage_seconds": {"stage1": 7.5}}))
    (run / "heldout" / "val" / "report.json").write_text(json.dumps(
        {"rows": [{"method": "m", "psnr": 2.0}], "stage_seconds": {}, "run": str(run), "heldout_from": "val"}))
    data = json.loads(tables.record(run / "heldout" / "val", "x", "cmd", None).read_text())
    assert data["rows"][0]["psnr"] == 2.0 and data["stage_seconds"] == {"stage1": 7.5}
    assert data["commit"] == "abc1234" and data["heldout_from"] == "val"


def test_a_mean_row_averages_the_files_it_names(benchmark_script, tmp_path, monkeypatch):
    tables = benchmark_script("results_table")
    monkeypatch.setattr(tables, "RESULTS", tmp_path)
    for stem, full, check in (("a", 20.0, "refine"), ("b", 21.0, "continue")):
        (tmp_path / f"{stem}.json").write_text(json.dumps({
            "rows": [{"method": "Full", "status": "ok", "psnr": full},
                     {"method": "STGS w/ COLMAP", "status": "failed" if stem == "b" else "ok", "psnr": 18.0}],
            "self_check": {"decision": check}, "commit": f"c{stem}", "date": f"2026-11-2{len(stem)}"}))
    mean = tables._read("mean:a,b")
    rows = {r["method"]: r for r in mean["rows"]}
    assert rows["Full"]["psnr"] == 20.5 and rows["STGS w/ COLMAP"]["status"] == "failed"
    assert mean["self_check"]["decision"] == "continue/refine" and mean["commit"] == "ca/cb"
    assert tables._read("mean:a,missing") is None
