"""Running the stage-2 self-check's fold (the settings and the decision rule: ``pipeline.self_check``)."""
from __future__ import annotations

import copy
import dataclasses
import logging
import time
from pathlib import Path
from typing import Any

import numpy as np

from fixer4d.pipeline.self_check import DECISION_FILE, decide

log = logging.getLogger("fixer4d.pipeline")


def _held_back_psnr(model, views, cam: int, frames: list[int], backend: str, background) -> float:
    """Mean PSNR of ``model`` at train camera ``cam`` of the fold over ``frames``."""
    from fixer4d.eval.metrics import psnr
    from fixer4d.render.views import render_views

    scores = []
    for f in frames:
        rgb = render_views(model, [views.cameras[cam]], views.time(f), backend, background)[0][0]
        scores.append(psnr(rgb, views.frame(f, cam)))
    return float(np.mean(scores))


def run_self_check(scene, config, out_dir: str | Path, restorer, *, progress: bool = False) -> dict[str, Any]:
    """The self-check of ``config`` on ``scene`` (module docstring) with the run's ``restorer``;
    working files under ``out_dir``. Returns the decision record (also ``out_dir/decision.json``)."""
    from fixer4d import atomic
    from fixer4d.init import load_frame_clouds, run_init
    from fixer4d.init.decompose import DecomposedInit, has_decomposed
    from fixer4d.model.camera_response import CameraResponse
    from fixer4d.pipeline.keys import stage2_key
    from fixer4d.pipeline.restoration import make_refresh_callback
    from fixer4d.restore.cache import RestoreCache
    from fixer4d.scene.train_view import TrainOnlyView
    from fixer4d.train.config import matched_config
    from fixer4d.train.model_init import model_from_init
    from fixer4d.train.trainer import Trainer

    sc = config.self_check
    out_dir = Path(out_dir)
    train_ids = list(scene.train_ids)
    if len(train_ids) < 3:
        record = {"decision": "refine", "reason": f"{len(train_ids)} train cameras: no fold of at least 2 to check on"}
        atomic.write_json(out_dir / DECISION_FILE, record)
        return record
    held = train_ids[sc.fold % len(train_ids)]
    views = TrainOnlyView(scene, [i for i in train_ids if i != held], sc.scale)
    seconds: dict[str, float] = {}
    t0 = time.perf_counter()
    frames = list(range(0, scene.num_frames, config.init_frame_stride))
    init_dir = out_dir / "init"
    run_init(views, config.init.method, init_dir, frames=frames, config=config.init, progress=False)
    init = DecomposedInit.load(init_dir) if has_decomposed(init_dir) else load_frame_clouds(init_dir)
    seconds["init"] = time.perf_counter() - t0

    cfg1 = dataclasses.replace(config.stage1, progress=progress)
    t0 = time.perf_counter()
    model, effects_decision = model_from_init(init, views, cfg1, config.effects)
    response = (CameraResponse(len(views.train_ids)) if effects_decision is not None and effects_decision.camera_response
                else None)
    trainer = Trainer(model, views, cfg1, effects=config.effects if effects_decision is not None else None,
                      camera_response=response)
    trainer.train(progress=progress)
    base = trainer.model
    seconds["stage1"] = time.perf_counter() - t0
    eval_frames = sorted({int(round(x)) for x in np.linspace(0, scene.num_frames - 1, sc.eval_frames)})
    background = trainer.background
    backend = cfg1.backend
    psnr = {"skip": _held_back_psnr(base, views, held, eval_frames, backend, background)}

    t0 = time.perf_counter()
    cont = Trainer(copy.deepcopy(base), views, matched_config(cfg1, config.stage2), camera_response=copy.deepcopy(response))
    cont.train(progress=progress)
    psnr["continue"] = _held_back_psnr(cont.model, views, held, eval_frames, backend, background)
    seconds["continue"] = time.perf_counter() - t0
    del cont

    t0 = time.perf_counter()
    refresh = make_refresh_callback(out_dir, views, config, progress=progress, backend=backend, restorer=restorer)
    refine = Trainer(copy.deepcopy(base), views, cfg1, stage2=config.stage2,
                     cache=RestoreCache(out_dir / "cache", fingerprint=stage2_key(config)), refresh_cache=refresh,
                     camera_response=copy.deepcopy(response))
    refine.train(progress=progress)
    psnr["refine"] = _held_back_psnr(refine.model, views, held, eval_frames, backend, background)
    seconds["refine"] = time.perf_counter() - t0

    decision = decide(psnr, sc.tie_db, sc.allow_skip)
    record = {
        "decision": decision,
        "held_back_camera": int(held),
        "fold_cameras": [int(i) for i in views.train_ids],
        "scale": sc.scale,
        "frames": eval_frames,
        "psnr": psnr,
        "gain_refine_db": psnr["refine"] - psnr["skip"],
        "gain_continue_db": psnr["continue"] - psnr["skip"],
        "settings": {"lambda_gen": config.stage2.lambda_gen, "pseudo_mask": config.stage2.pseudo_mask,
                     "stage2_iterations": config.stage2.total_iterations, "restorer": config.restorer.kind,
                     "tie_db": sc.tie_db, "allow_skip": sc.allow_skip},
        "seconds": seconds,
        "reason": _reason(decision, psnr),
    }
    atomic.write_json(out_dir / DECISION_FILE, record)
    log.info("stage-2 self-check on train camera %s: %s", held, record["reason"])
    return record


def _reason(decision: str, psnr: dict[str, float]) -> str:
    figures = ", ".join(f"{k} {v:.2f} dB" for k, v in psnr.items())
    what = {"skip": "no more training: stage 2 and the longer control both lowered the held-back camera",
            "continue": "more training on the observed views, without pseudo-views: the pseudo-loss did not pay",
            "refine": "stage 2 with pseudo-views: it beat the same amount of plain training on the held-back "
                      "camera"}[decision]
    return f"{decision} ({what}; held-back train camera: {figures})"


__all__ = ["run_self_check"]
