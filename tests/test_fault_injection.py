"""Fault injection: the tiny pipeline SIGKILLed in its training stages and resumed
ends with the uninterrupted run's report, byte-identical artifacts, no temporary files left,
and no stale cache entry served after a config change. ``benchmarks/fault_injection.py`` is
the full version (>= 10 kills spread over every stage); this test uses 2 kills and the
script's FAST_SETTINGS. It caught a real divergence: stage 1 trained from the init clouds in
memory (float colours) when the init ran in the same process, but from the clouds on disk
(uint8 colours) after a kill, so the resumed run's metrics differed in the 4th digit."""
from __future__ import annotations

import json
import random

import pytest


@pytest.fixture(scope="module")
def fi(benchmark_script):
    return benchmark_script("fault_injection")


def test_checks_catch_what_they_are_for(fi, tmp_path):
    ref = {"rows": [{"method": "Full", "psnr": 20.0, "dssim1": 0.1, "dssim2": 0.1, "lpips": None, "seconds": 3.0}]}
    same_but_slower = json.loads(json.dumps(ref))
    same_but_slower["rows"][0]["seconds"] = 9.0
    assert fi.compare_reports(ref, same_but_slower) == []
    off = json.loads(json.dumps(ref))
    off["rows"][0]["psnr"] = 20.000000001
    assert fi.compare_reports(ref, off) == ["row 'Full': psnr 20.0 (reference) != 20.000000001"]

    run = tmp_path / "run"
    (run / "cache" / "round_0" / ".t0000_0-1.tmp.ab12").mkdir(parents=True)
    (run / "checkpoints").mkdir()
    (run / "checkpoints" / ".stage1_0000010.pt.x9y8.pt").write_bytes(b"")
    (run / "checkpoints" / "stage1_0000010.pt").write_bytes(b"")
    (run / "cache" / "corrupt").mkdir()
    assert fi.leftovers(run) == ["cache/corrupt", "cache/round_0/.t0000_0-1.tmp.ab12",
                                 "checkpoints/.stage1_0000010.pt.x9y8.pt"]

    a, b = tmp_path / "a", tmp_path / "b"
    for d, psnr, secs in ((a, 20.0, 1.0), (b, 20.0, 5.0)):
        (d / "eval" / "full").mkdir(parents=True)
        (d / "eval" / "full" / "metrics.json").write_text(json.dumps({"mean": {"psnr": psnr}, "seconds": {"eval": secs},
                                                                      "render_seconds": secs}))
        (d / "model_final.ply").write_bytes(b"ply")
    assert fi.compare_artifacts(a, b) == []  # only wall times differ
    (b / "model_final.ply").write_bytes(b"plz")
    assert fi.compare_artifacts(a, b) == ["model_final.ply: content differs"]


def test_kill_plan_covers_every_stage(fi):
    durations = {"init_mvs": 5.0, "stage1": 6.0, "eval:x": 1.0, "stage2": 3.0, "eval:full": 0.2}
    plan = fi.plan_kills(durations, 10, random.Random(0))
    assert len(plan) == 10 and {s for s, _ in plan} == set(durations)
    assert [s for s, _ in plan] == sorted((s for s, _ in plan), key=list(durations).index)
    assert all(fi.KILL_FRACTION[0] * durations[s] <= d <= fi.KILL_FRACTION[1] * durations[s] for s, d in plan)


@pytest.mark.slow
def test_killed_and_resumed_run_equals_the_uninterrupted_one(fi, tmp_path):
    # stage 1 killed early (before its first checkpoint: the resume starts the stage over from the
    # init clouds on disk) and stage 2 mid-way (resumes from a checkpoint, cache partly written)
    result = fi.run_experiment(tmp_path, 2, fi.FAST_SETTINGS, seed=0, change=fi.DEFAULT_CHANGE,
                               targets=[("stage1", 0.1), ("stage2", 0.6)], references=1, log=lambda *_: None)
    assert result["ok"], "\n".join(result["problems"])
    assert result["kills"] == 2 and result["metric_tolerance"] == 0.0
    assert result["config_change"]["outcome"] in ("refused", "recomputed")
