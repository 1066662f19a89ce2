"""benchmarks/stage2_ceiling.py: stage 2 with ground-truth pseudo-targets, through the pipeline's
own stage function and refresh callback (the restorer is the only thing it replaces)."""
from __future__ import annotations

import json

import numpy as np
import pytest


@pytest.fixture(scope="module")
def ceiling(benchmark_script):
    return benchmark_script("stage2_ceiling")


def test_oracle_targets_are_the_ground_truth_and_the_rows_are_reported(ceiling, tiny_run, tmp_path):
    from fixer4d.pipeline.run_folder import read_run_config
    from fixer4d.restore.cache import RestoreCache
    from fixer4d.pipeline.run_folder import load_scene_for

    run_dir, _ = tiny_run
    out = tmp_path / "oracle"
    assert ceiling.main([str(run_dir), "--out", str(out)]) == 0
    doc = json.loads((out / "ceiling.json").read_text())
    rows = {r["method"]: r for r in doc["rows"]}
    assert {"STGS w/ MVS", "STGS w/ MVS (matched iterations)", "Full", "Full (oracle pseudo-targets)"} <= set(rows)
    assert np.isfinite(rows["Full (oracle pseudo-targets)"]["psnr"])
    assert (out / "ceiling.md").read_text().count("|") > 10

    # every cached pseudo-target is the scene's ray-cast truth at the trajectory camera (8-bit PNG)
    scene = load_scene_for(read_run_config(run_dir))
    entries = RestoreCache(out / "cache").entries(None)
    assert entries
    entry = entries[0]
    k = len(entry.cameras) // 2
    truth = np.clip(scene.render_gt(entry.cameras[k], float(entry.time))[0], 0, 1)
    assert np.abs(entry.rgb()[k] - truth).max() <= 1.0 / 255 + 1e-6
    # the run's config but for the oracle's ungated targets
    ran = json.loads((out / "config.json").read_text())["config"]
    source = json.loads((run_dir / "config.json").read_text())["config"]
    assert ran["stage2"].pop("pseudo_target") == "restored"
    source["stage2"].pop("pseudo_target")
    assert ran == source


def test_only_stage2_and_trajectory_settings_may_change(ceiling, tiny_run, tmp_path):
    run_dir, _ = tiny_run
    with pytest.raises(SystemExit, match="training.iterations"):
        ceiling.main([str(run_dir), "--out", str(tmp_path / "x"), "--set", "training.iterations=5"])
