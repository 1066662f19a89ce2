"""The pipeline records the stage-1 model's effects (report.json "model") and obeys --effects."""
from __future__ import annotations

import json

import pytest

from fixer4d.pipeline.config import resolve
from fixer4d.pipeline.run import run_pipeline

TINY = {"training.iterations": 20, "stage2.rounds": 0, "init_frame_stride": 1, "eval.stride": 2,
        "init.mvs.planes": 32, "baseline_sparse": False, "eval.restoration_rows": False}


@pytest.mark.parametrize("mode", ["auto", "static"])
def test_report_has_the_model_section(tmp_path, mode):
    cfg = resolve("tiny", overrides={**TINY, "effects.mode": mode})
    report = run_pipeline(cfg, tmp_path, progress=False)
    on_disk = json.loads((tmp_path / "report.json").read_text())
    assert on_disk["model"] == report["model"]
    model = report["model"]
    assert model["mode"] == mode and model["static"] + model["dynamic"] == model["gaussians"]
    assert set(model["reasons"]) >= {"motion_degree", "rotation_velocity", "temporal_opacity", "sh_degree"}
    if mode == "static":
        assert model["dynamic"] == 0 and model["config"]["motion_degree"] == 0
        assert not model["config"]["temporal_opacity"]
    else:  # the tiny scene's ball moves
        assert model["config"]["temporal_opacity"] and model["dynamic"] > 0
        assert set(model["revisions"]) == {"demoted", "split_dynamic"}
    assert (tmp_path / "init_mvs" / "decomposed.npz").exists() and (tmp_path / "init_mvs" / "masks.npz").exists()
