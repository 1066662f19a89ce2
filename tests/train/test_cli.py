"""`fixer4d reconstruct` and `fixer4d refine` on the tiny scene: run folder contract, init reuse,
resume, metrics."""
from __future__ import annotations

import json

import numpy as np
import pytest

from fixer4d.cli import main


@pytest.fixture
def run_with_init(tmp_path, small_clouds):
    """A run folder whose init/ already holds clouds (reconstruct must reuse them, not re-run MVS)."""
    from fixer4d.atomic import write_json
    from fixer4d.init import save_frame_clouds

    run = tmp_path / "run"
    save_frame_clouds(run / "init", small_clouds)
    write_json(run / "init" / "init_report.json", {"method": "mvs", "seconds": {"preparation": 1.5, "total": 2.0}})
    return run


def test_reconstruct_then_refine(run_with_init, tiny_scene, monkeypatch):
    run = run_with_init
    small_scene = tiny_scene  # the run is at full tiny resolution (LPIPS needs >= 31 px)
    args = ["reconstruct", "tiny", "--init", "mvs", "--out", str(run), "--iterations", "12", "--resolution", "1.0",
            "--no-progress", "--eval-stride", "2"]
    assert main(args) == 0
    config = json.loads((run / "config.json").read_text())
    assert config["scene"] == {"source": "tiny", "scale": 1.0, "frame_range": None}
    assert config["stage1"]["iterations"] == 12 and config["init"]["method"] == "mvs"
    assert (run / "model_stage1.ply").is_file()
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["seconds"]["prep"] == pytest.approx(1.5)
    assert metrics["seconds"]["train"] > 0 and metrics["seconds"]["eval"] > 0
    assert np.isfinite(metrics["mean"]["psnr"]) and (run / "eval" / "stage1" / "metrics.json").is_file()
    ckpts = sorted(p.name for p in (run / "checkpoints").iterdir() if p.suffix == ".pt")
    assert ckpts[-1] == "stage1_0000012.pt" and len(ckpts) <= 2  # the newest keep_checkpoints

    # a rerun resumes from the finished checkpoint instead of training again
    assert main(args) == 0
    assert json.loads((run / "eval" / "stage1" / "metrics.json").read_text())["mean"] == metrics["mean"]

    # stage 2 on a cache with one restored clip (here: ground truth), no pipeline refresh
    from fixer4d.restore.base import RestoreRequest, RestoreResult
    from fixer4d.restore.cache import RestoreCache
    from fixer4d.geometry.trajectory import interpolate_pair
    import fixer4d.train.refine_cli as refine_cli

    i, j = sorted(small_scene.train_ids)[:2]
    cams = interpolate_pair(small_scene.cameras[i], small_scene.cameras[j], [0.3, 0.7])
    gt = np.stack([small_scene.render_gt(c, small_scene.time(1))[0] for c in cams])
    h, w = gt.shape[1:3]
    one = np.ones((h, w), np.float32)
    req = RestoreRequest(rgb=gt, depth=np.ones((2, h, w), np.float32), alpha=np.ones((2, h, w), np.float32),
                         cameras=cams, time=small_scene.time(1), frame=1,
                         ref_images=[small_scene.frame(1, i), small_scene.frame(1, j)],
                         ref_cameras=[small_scene.cameras[i], small_scene.cameras[j]], ref_depths=[one, one],
                         ref_alphas=[one, one])
    res = RestoreResult(rgb=gt, confidence=np.ones((2, h, w), np.float32), frame_confidence=np.ones(2, np.float32))
    RestoreCache(run / "cache").write(0, RestoreCache.key(1, i, j), req, res, {"step": 12})
    monkeypatch.setattr(refine_cli, "load_refresh_callback", lambda *a, **k: None)
    assert main(["refine", str(run), "--iterations", "6", "--refresh-every", "6", "--rounds", "1",
                 "--lambda-gen", "0.5", "--no-progress", "--eval-stride", "2"]) == 0
    assert (run / "model_final.ply").is_file()
    config = json.loads((run / "config.json").read_text())
    assert config["stage2"]["iterations"] == 6 and config["stage1"]["iterations"] == 12
    final = json.loads((run / "metrics.json").read_text())
    assert final["method"] == "Full" and final["seconds"]["train"] > metrics["seconds"]["train"]


def test_reconstruct_rejects_a_bad_frame_range(tmp_path, capsys):
    assert main(["reconstruct", "tiny", "--out", str(tmp_path / "r"), "--frames", "3:1"]) == 1
    assert "--frames" in capsys.readouterr().err
