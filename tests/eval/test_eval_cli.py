"""`fixer4d eval RUN` on a run folder holding the bundled "tiny" scene and a small random model."""
import json

import numpy as np
import pytest

from fixer4d.cli import main
from fixer4d.errors import InputError
from fixer4d.eval.cli import find_model, known_seconds, method_name_for


@pytest.fixture()
def run_dir(tmp_path):
    from fixer4d.model.io import save_ply
    from fixer4d.model.spacetime import SpacetimeGaussians

    rng = np.random.default_rng(0)
    n = 300
    points = rng.uniform([-1.0, 0.0, -1.0], [1.0, 1.2, 1.0], size=(n, 3))
    model = SpacetimeGaussians.from_points(points, rng.uniform(0, 1, (n, 3)), rng.uniform(0, 1, n), opacity=0.5)
    run = tmp_path / "run"
    run.mkdir()
    save_ply(model, run / "model_stage1.ply")
    (run / "config.json").write_text(json.dumps({"scene": {"source": "tiny", "scale": 1.0, "frame_range": None},
                                                 "init": {"method": "mvs"},
                                                 "stage1": {"background": [0.5, 0.6, 0.7]}}))
    (run / "report.json").write_text(json.dumps({"seconds": {"prep": 3.5, "train": 40.0, "init": 3.5}}))
    return run


def test_eval_verb_writes_run_metrics(run_dir, capsys):
    assert main(["eval", str(run_dir), "--stride", "2", "--backend", "reference", "--quiet", "--examples", "1"]) == 0
    res = json.loads((run_dir / "metrics.json").read_text())
    assert res["method"] == "STGS (mvs init)"
    assert res["model"].endswith("model_stage1.ply")
    assert res["seconds"]["prep"] == 3.5 and res["seconds"]["train"] == 40.0 and res["seconds"]["eval"] > 0
    assert res["protocol"]["frames"] == [0, 2]
    assert len(res["per_view"]) == 4 and len(res["per_frame"]) == 8  # tiny: 4 held-out cameras
    assert np.isfinite(res["mean"]["psnr"]) and 0 < res["mean"]["dssim1"] < 0.5
    assert json.loads((run_dir / "eval" / "stgs-mvs-init" / "metrics.json").read_text()) == res
    assert len(list((run_dir / "eval" / "stgs-mvs-init").glob("example_*.png"))) == 4
    assert "| STGS (mvs init) |" in capsys.readouterr().out


def test_eval_verb_errors(tmp_path, capsys):
    assert main(["eval", str(tmp_path)]) == 1
    assert "config.json" in capsys.readouterr().err
    with pytest.raises(InputError, match="model_final.ply or model_stage1.ply"):
        find_model(tmp_path)


def test_helpers(tmp_path):
    (tmp_path / "model_final.ply").write_bytes(b"")
    (tmp_path / "model_stage1.ply").write_bytes(b"")
    assert find_model(tmp_path).name == "model_final.ply"
    assert method_name_for(tmp_path / "model_final.ply", {}) == "4DGS-Fixer"
    assert method_name_for(tmp_path / "model_stage1.ply", {"init": {"method": "sparse"}}) == "STGS (sparse init)"
    assert method_name_for(tmp_path / "model_stage1.ply", {"pipeline": {"init": {"method": "mvs"}}}) == "STGS (mvs init)"
    assert known_seconds(tmp_path) == {}
    (tmp_path / "metrics.json").write_text(json.dumps({"seconds": {"prep": None, "train": 7}}))
    assert known_seconds(tmp_path) == {"train": 7.0}
    # `fixer4d run` folders: per-stage seconds in stages.json / report.json["stage_seconds"]
    (tmp_path / "stages.json").write_text(json.dumps({"init_mvs": 5.0, "init_sparse": 2.0, "stage1": 30.0,
                                                      "stage2": 50.0}))
    assert known_seconds(tmp_path, tmp_path / "model_stage1.ply", "sparse") == {"prep": 2.0, "train": 30.0}
    assert known_seconds(tmp_path, tmp_path / "model_final.ply", "mvs") == {"prep": 5.0, "train": 80.0}
