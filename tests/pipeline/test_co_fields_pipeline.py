"""co_fields in the pipeline: the twin field beside stage 1, and its disagreement as the per-pixel
weight of the restoration requests (pipeline.restoration.make_request, co_fields.weight)."""
from __future__ import annotations

import copy

import numpy as np
import torch

from pipeline_tiny import run_spied, tiny_config


def _request(run_dir, twin=None):
    from fixer4d.model.io import load_ply
    from fixer4d.pipeline.restoration import make_request
    from fixer4d.pipeline.run_folder import load_scene_for, read_run_config

    config = read_run_config(run_dir)
    scene = load_scene_for(config)
    cams = [scene.cameras[i] for i in scene.test_ids]
    return make_request(load_ply(run_dir / "model_stage1.ply"), scene, cams, 0, tuple(scene.train_ids[:2]),
                        visibility=config.stage2.visibility, twin=twin)


def test_the_twin_weight_replaces_or_raises_the_visibility_weight(tiny_run):
    from fixer4d.model.io import load_ply
    from fixer4d.pipeline.restoration import TwinWeight

    run_dir, _ = tiny_run
    visibility = _request(run_dir).unobserved
    same = load_ply(run_dir / "model_stage1.ply")
    assert not _request(run_dir, TwinWeight(same, "undetermined")).unobserved.any()
    np.testing.assert_array_equal(_request(run_dir, TwinWeight(same, "max")).unobserved, visibility)
    moved = copy.deepcopy(same)
    with torch.no_grad():
        moved.means += 0.2 * moved.means.std(dim=0)  # a field that disagrees everywhere it renders
    undetermined = _request(run_dir, TwinWeight(moved, "undetermined")).unobserved
    assert undetermined.max() > 0.5
    highest = _request(run_dir, TwinWeight(moved, "max")).unobserved
    np.testing.assert_array_equal(highest, np.maximum(visibility, undetermined))


def test_a_run_with_co_fields_saves_the_twin_and_gates_by_the_combined_weight(tmp_path, stage_cache):
    from fixer4d.pipeline.run_folder import read_run_config

    run_dir = tmp_path / "co"
    report, spy = run_spied(tiny_config(**{"co_fields.enabled": True, "co_fields.weight": "max", "training.fields": 1,
                                           "self_check.enabled": False}), run_dir, stage_cache)
    assert (run_dir / "model_stage1.ply").is_file() and (run_dir / "model_stage1_twin.ply").is_file()
    assert read_run_config(run_dir).co_fields.enabled
    assert not list((run_dir / "twin" / "checkpoints").glob("*.pt"))  # a finished stage drops them
    assert not spy.violations
    rows = {r["method"]: r for r in report["rows"]}
    assert rows["Full"]["status"] == "ok" and rows["Restoration (init)"]["status"] == "ok"
