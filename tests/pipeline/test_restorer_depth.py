"""benchmarks/restorer_depth.py: the warp restorer at the held-out views with the model's depth
and with the true depth."""
from __future__ import annotations

import json

import numpy as np
import pytest


@pytest.fixture(scope="module")
def diag(benchmark_script):
    return benchmark_script("restorer_depth")


def test_true_depth_request_replaces_every_depth(diag, tiny_run):
    from fixer4d.model.io import load_ply
    from fixer4d.pipeline.restoration import make_request
    from fixer4d.pipeline.run_folder import load_scene_for, read_run_config

    run_dir, _ = tiny_run
    scene = load_scene_for(read_run_config(run_dir))
    cam = scene.cameras[scene.test_ids[0]]
    req = make_request(load_ply(run_dir / "model_stage1.ply"), scene, [cam], 0, tuple(scene.train_ids[:2]))
    true = diag.true_depth_request(req, scene)
    np.testing.assert_array_equal(true.depth[0], scene.render_gt(cam, req.time)[1].astype(np.float32))
    np.testing.assert_array_equal(true.ref_depths[1], scene.render_gt(req.ref_cameras[1], req.time)[1].astype(np.float32))
    assert len(true.extra_depths) == len(req.extra_depths) and np.all(true.alpha == 1.0)
    assert not np.array_equal(req.depth, true.depth)  # the request itself is left as it was


def test_report_per_view_and_mean(diag, tiny_run, tmp_path, capsys):
    run_dir, _ = tiny_run
    out = tmp_path / "depth.json"
    assert diag.main([str(run_dir), "--frames", "0", "--out", str(out)]) == 0
    doc = json.loads(out.read_text())
    from fixer4d.pipeline.run_folder import load_scene_for, read_run_config

    assert len(doc["views"]) == len(load_scene_for(read_run_config(run_dir)).test_ids)
    assert all(np.isfinite(v) for v in doc["mean"].values())
    assert "warp, true depth" in capsys.readouterr().out
