"""The pipeline records the stage-1 model's terms (report.json "model") and obeys model_terms.mode."""
from __future__ import annotations

import json

import pytest

from fixer4d.pipeline.config import resolve
from fixer4d.pipeline.run import run_pipeline

TINY = {"training.iterations": 20, "stage2.rounds": 0, "init_frame_stride": 1, "eval.stride": 2,
        "init.mvs.planes": 32, "baseline_sparse": False, "eval.restoration_rows": False}


@pytest.mark.parametrize("mode", ["auto", "static"])
def test_report_has_the_model_section(tmp_path, mode):
    cfg = resolve("tiny", overrides={**TINY, "model_terms.mode": mode})
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


def test_a_run_folder_with_the_former_terms_file_still_reports_it(tmp_path):
    """A run folder made before the rename keeps its terms in model_effects.json: a resumed run
    reads them from there (the report's "model" section) and writes no model_terms.json."""
    cfg = resolve("tiny", overrides=TINY)
    first = run_pipeline(cfg, tmp_path, progress=False)
    (tmp_path / "model_terms.json").rename(tmp_path / "model_effects.json")
    (tmp_path / "report.json").unlink()
    again = run_pipeline(cfg, tmp_path, progress=False)
    assert again["model"] == first["model"] and not (tmp_path / "model_terms.json").exists()
