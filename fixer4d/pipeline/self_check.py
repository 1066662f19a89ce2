"""Stage 2's self-check: does pseudo-supervision help on this scene? Asked of a train camera.

A held-out camera may never decide anything, yet stage 2 can lower a real capture's quality
(pseudo-targets that contradict the real views; more training on four views that already
overfits). So the run asks one of its own train cameras, held back:

1. a fold: the scene seen through the other train cameras only (``TrainOnlyView`` at
   ``scale``), its own init from those cameras, stage 1 on them (the run's stage-1 settings);
2. from that model, two continuations of stage 2's length: *continue* (more stage-1 training,
   no pseudo-views: the matched-iterations control) and *refine* (stage 2 as configured: the
   run's restorer, trajectories between the fold's cameras, pseudo-loss);
3. the held-back camera's PSNR before (*skip*: no more training), after *continue* and after
   *refine*, on ``eval_frames`` frames spread over the clip.

The decision is the best of the three (ties within ``tie_db`` go to the one that changes less:
skip, then continue), and the run's final model follows it: *refine* runs stage 2, *continue*
keeps the matched-iterations control, *skip* keeps the stage-1 model. Its figures and seconds go
into the report. The learned restorer never trains on the held-back camera's frames as targets
(it is that restorer's validation fold), so the check does not see its own answer.
"""
from __future__ import annotations

import copy
import dataclasses
import logging
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from fixer4d.errors import InputError

log = logging.getLogger("fixer4d.pipeline")

CHOICES = ("skip", "continue", "refine")
DECISION_FILE = "decision.json"


@dataclass
class SelfCheckConfig:
    """The stage-2 self-check (module docstring).

    enabled: run it (False: stage 2 always runs, as in the paper).
    fold: index into the scene's train cameras of the one held back (taken modulo their count);
      3 is the learned restorer's validation fold (``restorer.learned.validation_fold``), the
      camera whose frames that restorer never learns from.
    scale: resolution of the fold's trainings (0.5: a quarter of the pixels, ~4x cheaper).
    eval_frames: frames of the held-back camera scored, spread over the clip.
    tie_db: a choice must beat a simpler one by more than this to be taken: PSNR differences of
      a few hundredths of a dB on one camera are noise.
    """

    enabled: bool = True
    fold: int = 3
    scale: float = 0.5
    eval_frames: int = 6
    tie_db: float = 0.02

    def __post_init__(self) -> None:
        if not 0.0 < self.scale <= 1.0:
            raise InputError(f"self_check.scale must be in (0, 1], got {self.scale}")
        if self.eval_frames < 1 or self.fold < 0 or self.tie_db < 0:
            raise InputError("self_check: eval_frames >= 1, fold >= 0 and tie_db >= 0 are needed")


def decide(psnr: dict[str, float], tie_db: float) -> str:
    """The best of ``psnr`` ({"skip", "continue", "refine"} -> dB); a later choice must beat every
    earlier (simpler) one by more than ``tie_db``."""
    best = CHOICES[0]
    for choice in CHOICES[1:]:
        if choice in psnr and psnr[choice] > psnr[best] + tie_db:
            best = choice
    return best


def _held_back_psnr(model, views, cam: int, frames: list[int], backend: str, background) -> float:
    """Mean PSNR of ``model`` at train camera ``cam`` of the fold over ``frames``."""
    from fixer4d.eval.metrics import psnr
    from fixer4d.pipeline.restoration import render_views

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
    from fixer4d.pipeline.keys import stage2_key
    from fixer4d.pipeline.restoration import make_refresh_callback
    from fixer4d.pipeline.stages import matched_config
    from fixer4d.restore.cache import RestoreCache
    from fixer4d.scene.train_view import TrainOnlyView
    from fixer4d.train.trainer import Trainer, model_from_init

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
    trainer = Trainer(model, views, cfg1, effects=config.effects if effects_decision is not None else None)
    trainer.train(progress=progress)
    base = trainer.model
    seconds["stage1"] = time.perf_counter() - t0
    eval_frames = sorted({int(round(x)) for x in np.linspace(0, scene.num_frames - 1, sc.eval_frames)})
    background = trainer.background
    backend = cfg1.backend
    psnr = {"skip": _held_back_psnr(base, views, held, eval_frames, backend, background)}

    t0 = time.perf_counter()
    cont = Trainer(copy.deepcopy(base), views, matched_config(cfg1, config.stage2))
    cont.train(progress=progress)
    psnr["continue"] = _held_back_psnr(cont.model, views, held, eval_frames, backend, background)
    seconds["continue"] = time.perf_counter() - t0
    del cont

    t0 = time.perf_counter()
    refresh = make_refresh_callback(out_dir, views, config, progress=progress, backend=backend, restorer=restorer)
    refine = Trainer(copy.deepcopy(base), views, cfg1, stage2=config.stage2,
                     cache=RestoreCache(out_dir / "cache", fingerprint=stage2_key(config)), refresh_cache=refresh)
    refine.train(progress=progress)
    psnr["refine"] = _held_back_psnr(refine.model, views, held, eval_frames, backend, background)
    seconds["refine"] = time.perf_counter() - t0

    decision = decide(psnr, sc.tie_db)
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
                     "tie_db": sc.tie_db},
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
            "refine": "stage 2 with pseudo-views: it raised the held-back camera most"}[decision]
    return f"{decision} ({what}; held-back train camera: {figures})"


__all__ = ["SelfCheckConfig", "run_self_check", "decide", "CHOICES", "DECISION_FILE"]
