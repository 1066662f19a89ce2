"""A finished run scored on another folder's held-out cameras (same train cameras, other held-out ones).

Settings are chosen on validation cameras and reported on test cameras. A validation folder
holds the same train cameras (identical images and calibration) as its test folder and other
held-out cameras, so everything a run trained is valid for both; only the scoring differs.
``evaluate_on_other_cameras(run, other)`` checks that the train cameras really are the same
(ids, intrinsics, poses and the pixels of every train camera's first and last frame), then scores
the run's models on ``other``'s held-out cameras into ``RUN/heldout/<other's name>/`` with the
run's own protocol (stride, rows, unobserved-pixel region): report.md / report.json there.
"""
from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import numpy as np

from fixer4d.errors import InputError


def check_same_train_cameras(a, b) -> None:
    """Raise InputError unless scenes ``a`` and ``b`` have the same train cameras (ids, K, pose,
    size, frame count and the pixels of their first and last frames)."""
    if list(a.train_ids) != list(b.train_ids):
        raise InputError(f"train cameras differ: {list(a.train_ids)} vs {list(b.train_ids)}; a validation folder "
                         "must hold the run's own train cameras")
    if a.num_frames != b.num_frames:
        raise InputError(f"frame counts differ: {a.num_frames} vs {b.num_frames}")
    for i in a.train_ids:
        ca, cb = a.cameras[i], b.cameras[i]
        if (ca.width, ca.height) != (cb.width, cb.height) or not (np.allclose(ca.K, cb.K) and np.allclose(ca.c2w, cb.c2w)):
            raise InputError(f"train camera {i} has another size, intrinsics or pose in the other folder")
        for f in {0, a.num_frames - 1}:
            if not np.array_equal(a.frame(f, i), b.frame(f, i)):
                raise InputError(f"train camera {i}, frame {f}: the images differ; the run never saw these frames")
    overlap = set(a.train_ids) & set(b.test_ids)
    if overlap:
        raise InputError(f"cameras {sorted(overlap)} are held out in the other folder but trained in the run")


def evaluate_on_other_cameras(run_dir: str | Path, other: str | Path, *, progress: bool = True) -> dict[str, Any]:
    """Score the run's models on the held-out cameras of scene ``other`` (a folder or any scene
    source ``load_scene`` opens; module docstring) -> RUN/heldout/<its name>/; returns the report."""
    from fixer4d.eval.evaluate import evaluate
    from fixer4d.model.io import load_ply
    from fixer4d.pipeline import report as R
    from fixer4d.pipeline.restoration import UnobservedMasks, blur_render_fn, restoration_render_fn, run_restorer
    from fixer4d.pipeline.run_folder import RunFolder, load_scene_for
    from fixer4d.pipeline.self_check import DECISION_FILE
    from fixer4d.render.views import model_render_fn
    from fixer4d.train.background import resolve_background

    folder = RunFolder.open(run_dir)
    config = folder.config
    other_path = Path(other)
    source = str(other_path.resolve()) if other_path.exists() else str(other)
    other_config = dataclasses.replace(config, scene=dataclasses.replace(config.scene, source=source))
    scene = load_scene_for(other_config)
    check_same_train_cameras(folder.scene, scene)
    out = folder.path / "heldout" / Path(source).name
    ev = config.eval
    bg = resolve_background(config.training.background, folder.scene)
    stage1_path = folder.path / "model_stage1.ply"
    if not stage1_path.is_file():
        raise InputError(f"{folder.path}: no model_stage1.ply; run `fixer4d run` to the end first")
    stage1 = load_ply(stage1_path).eval()
    unobserved = UnobservedMasks(stage1, scene, config.stage2.visibility)
    rows: list[dict[str, Any]] = []

    def score(name: str, render_fn) -> dict[str, Any]:
        from fixer4d.pipeline.stages import eval_slug

        m = evaluate(render_fn, scene, out / eval_slug(name), frame_stride=ev.stride, method_name=name,
                     save_examples=ev.examples, progress=progress, unobserved_fn=unobserved)
        rows.append(R.metrics_row(name, m, None))
        return m

    m = score(R.ROW_MVS, model_render_fn(stage1, "auto", bg))
    models = [(R.ROW_MATCHED, folder.path / "matched" / "model.ply"), (R.ROW_FULL, folder.path / "model_final.ply")]
    if ev.restoration_rows:
        rows.append(R.copied_row(R.ROW_IDENTITY, m))
        score(R.ROW_BLUR, blur_render_fn(stage1, ev.blur_sigma_px, "auto", bg))
        gate = config.stage2.visibility if config.eval.gate_restoration else None
        score(R.ROW_RESTORED_INIT, restoration_render_fn(stage1, scene, run_restorer(config, folder.path), "auto",
                                                         gate, ev.fill_unobserved, background=bg))
    for name, path in models:
        if path.is_file():
            score(name, model_render_fn(load_ply(path).eval(), "auto", bg))
    extra: dict[str, Any] = {"heldout_from": source, "run": str(folder.path)}
    decision = folder.path / "self_check" / DECISION_FILE
    if not config.self_check.enabled:
        extra["self_check"] = {"decision": "refine", "enabled": False, "reason": "self-check off"}
    elif decision.is_file():
        extra["self_check"] = json.loads(decision.read_text())
    return R.write_report(out, scene.describe(), rows, {}, extra)


__all__ = ["evaluate_on_other_cameras", "check_same_train_cameras"]
