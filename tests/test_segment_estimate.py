"""benchmarks/segment_estimate.py: the long-capture estimate follows its stated model."""
from __future__ import annotations

import json
from pathlib import Path

import pytest


@pytest.fixture(scope="module")
def estimate(benchmark_script):
    return benchmark_script("segment_estimate")


def _run(tmp_path: Path) -> Path:
    stages = {"init_mvs": 100.0, "stage1": 600.0, "stage2": 900.0, "eval:full": 10.0, "init_sparse": 20.0,
              "stage1_sparse": 300.0, "matched": 200.0}
    (tmp_path / "stages.json").write_text(json.dumps({k: {"key": "k", "seconds": v, "done": True} for k, v in stages.items()}))
    (tmp_path / "report.json").write_text(json.dumps({"scene": "cap: 5 cameras (4 train, 1 held out), 30 frames at 320x180"}))
    return tmp_path


def test_stages_scale_by_their_kind(tmp_path, estimate):
    seconds, frames, w, h = estimate.measured(_run(tmp_path))
    assert (frames, w, h) == (30, 320, 180)
    per = estimate.segment_seconds(seconds, frames, 60, 4.0, main_only=False)
    assert per["stage1"] == pytest.approx(600.0 * 4)        # fixed iterations: frames do not matter
    assert per["init_mvs"] == pytest.approx(100.0 * 2 * 4)   # per frame: twice the frames
    assert per["eval:full"] == pytest.approx(10.0 * 2 * 4)
    main = estimate.segment_seconds(seconds, frames, 60, 1.0, main_only=True)
    assert "stage1_sparse" not in main and "matched" not in main and "init_sparse" not in main


def test_wall_time_table(tmp_path, estimate, capsys):
    out = tmp_path / "est.json"
    assert estimate.main([str(_run(tmp_path)), "--frames", "300", "--segment-frames", "50", "--machines", "1", "7",
                          "--main-only", "--out", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert len(doc["segments"]) == 7
    one = sum(doc["segment_seconds"].values())
    assert one == pytest.approx(600 + 900 + (100 + 10) * 50 / 30)
    # independent segments: all seven at once on seven machines
    assert [r["waves"] for r in doc["rows"]] == [7, 1]
    assert doc["rows"][0]["hours"] == pytest.approx(7 * one / 3600)
    assert doc["rows"][1]["hours"] == pytest.approx(one / 3600)
    # shared static: the first segment runs alone, then the other six
    assert estimate.main([str(_run(tmp_path)), "--segment-frames", "50", "--machines", "1", "7", "--shared",
                          "--out", str(out)]) == 0
    assert [r["waves"] for r in json.loads(out.read_text())["rows"]] == [7, 2]
