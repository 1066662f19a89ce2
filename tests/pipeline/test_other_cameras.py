"""A run scored on another scene's held-out cameras (fixer4d eval --cameras-from): the train
cameras must be the run's own, and on the run's own cameras it reproduces the report."""
from __future__ import annotations

import pytest

from fixer4d.errors import InputError
from fixer4d.pipeline import report as R
from fixer4d.pipeline.other_cameras import check_same_train_cameras, evaluate_on_other_cameras
from fixer4d.scene import load_scene


def test_on_the_runs_own_cameras_it_reproduces_the_report(tiny_run):
    run_dir, report = tiny_run
    again = evaluate_on_other_cameras(run_dir, "tiny", progress=False)
    ours = {r["method"]: r for r in report["rows"]}
    for row in again["rows"]:
        assert row["psnr"] == pytest.approx(ours[row["method"]]["psnr"], abs=1e-9), row["method"]
    assert {r["method"] for r in again["rows"]} >= {R.ROW_MVS, R.ROW_FULL, R.ROW_RESTORED_INIT, R.ROW_BLUR}
    assert (run_dir / "heldout" / "tiny" / "report.md").is_file()


def test_other_train_cameras_are_refused():
    base = load_scene("tiny")
    other = load_scene("tiny", train_ids=list(base.train_ids[:3]) + [base.test_ids[0]],
                       test_ids=[base.train_ids[3]])
    with pytest.raises(InputError, match="train cameras differ"):
        check_same_train_cameras(base, other)
    check_same_train_cameras(base, load_scene("tiny", test_ids=list(base.test_ids[:2])))
