"""Running the stage-2 self-check's fold (the settings and the decision rule: ``pipeline.self_check``)."""
from __future__ import annotations

import copy
import dataclasses
import logging
import shutil
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

from fixer4d.pipeline.self_check import DECISION_FILE, decide, fold_fields, gains

log = logging.getLogger("fixer4d.pipeline")


def _held_back_psnr(model, views, cam: int, frames: list[int], backend: str, background) -> list[float]:
    """PSNR (dB) of ``model`` at train camera ``cam`` of the fold, one per frame of ``frames``."""
    from fixer4d.eval.metrics import psnr
    from fixer4d.render.views import render_views

    scores = []
    for f in frames:
        rgb = render_views(model, [views.cameras[cam]], views.time(f), backend, background)[0][0]
        scores.append(float(psnr(rgb, views.frame(f, cam))))
    return scores


# The fold's progress (finished parts' PSNR and seconds), rewritten after each part: a killed check
# resumes at the part it was in (the parts' trainers keep checkpoints in <part>/checkpoints/).
PARTS_FILE = "parts.json"
# The fold's stage-1 model and the camera response it trained (null when its cameras agree on colour).
FOLD_MODEL = "model_stage1.ply"
FOLD_RESPONSE = "camera_response.json"


class _Parts:
    """``{"psnr": {candidate: mean dB}, "frames": {candidate: [dB per scored frame]}, "seconds":
    {part: s}}`` of the finished parts, kept in PARTS_FILE."""

    def __init__(self, out_dir: Path) -> None:
        import json

        self.path = out_dir / PARTS_FILE
        data = json.loads(self.path.read_text()) if self.path.is_file() else {}
        self.psnr: dict[str, float] = dict(data.get("psnr", {}))
        self.frames: dict[str, list[float]] = dict(data.get("frames", {}))
        self.seconds: dict[str, float] = dict(data.get("seconds", {}))

    def finish(self, part: str, seconds: float | None = None, frames: list[float] | None = None) -> None:
        from fixer4d import atomic

        if seconds is not None:
            self.seconds[part] = float(seconds)
        if frames is not None:
            self.frames[part] = [float(x) for x in frames]
            self.psnr[part] = float(np.mean(self.frames[part]))
        atomic.write_json(self.path, {"psnr": self.psnr, "frames": self.frames, "seconds": self.seconds})


def _train(trainer, progress: bool):
    """Train ``trainer`` from its newest checkpoint under its run_dir (if any) to the end; returns
    (its model, seconds of training over every attempt); the checkpoints are removed after."""
    prior = trainer.train_seconds if trainer.resume() else 0.0
    t0 = time.perf_counter()
    trainer.train(progress=progress)
    seconds = time.perf_counter() - t0 + prior
    shutil.rmtree(trainer.run_dir, ignore_errors=True)
    return trainer.host_model(), seconds


def _fold_restorer(views, init_dir: Path, cfg1, base, out_dir: Path, config, parts: "_Parts", progress: bool):
    """The learned restorer of the fold: trained like the run's (``train_scene_restorer``) but on
    the fold's cameras, init and stage-1 model only, so that no pair it learns from (target,
    reference or extra view) holds a frame of the held-back camera. Resumable (its own folder)."""
    from fixer4d.train.restorer_pairs import train_scene_restorer

    init = _load_init(init_dir)
    t0 = time.perf_counter()
    restorer = train_scene_restorer(views, init, cfg1, out_dir / "restorer", config.restorer, progress=progress,
                                    model=base)
    if "restorer" not in parts.seconds:
        parts.finish("restorer", time.perf_counter() - t0)
    return restorer


def run_self_check(scene, config, out_dir: str | Path, restorer, *, progress: bool = False,
                   scene_from_config: bool = False) -> dict[str, Any]:
    """The self-check of ``config`` on ``scene`` (module docstring of ``pipeline.self_check``) with
    the run's ``restorer``; working files under ``out_dir`` (the first fold's in it, the others' in
    ``out_dir/fold<k>``). Returns the decision record (also ``out_dir/decision.json``).
    Resumable: the parts finished (PARTS_FILE, a fold's init and model) are reused and an
    interrupted training continues from its last checkpoint, so a resumed check decides as an
    uninterrupted one. scene_from_config: ``scene`` is the train view of ``load_scene_for(config)``
    (what the pipeline passes), so the fold's fields may train side by side in worker processes
    that load it again (``training.field_workers``)."""
    from fixer4d import atomic

    sc = config.self_check
    out_dir = Path(out_dir)
    train_ids = list(scene.train_ids)
    if len(train_ids) < 3:
        record = {"decision": "refine", "reason": f"{len(train_ids)} train cameras: no fold of at least 2 to check on"}
        atomic.write_json(out_dir / DECISION_FILE, record)
        return record
    out_dir.mkdir(parents=True, exist_ok=True)
    folds = []
    for k, held in enumerate(sc.held_back(train_ids)):
        if len(folds) and progress:
            print(f"[fixer4d] self-check: fold {k + 1} of {sc.cameras} (held-back camera {held})", flush=True)
        folds.append(_run_fold(scene, config, out_dir if k == 0 else out_dir / f"fold{k}", held, restorer, progress,
                               scene_from_config))

    candidates = sc.candidates()
    if len(folds) == 1:
        psnr, units = folds[0]["psnr"], folds[0]["psnr_frames"]
    else:  # the unit of the paired gains is the fold (its mean over the scored frames)
        psnr = {c: float(np.mean([f["psnr"][c] for f in folds])) for c in candidates}
        units = {c: [f["psnr"][c] for f in folds] for c in candidates}
    decision = decide(psnr, sc.tie_db, sc.allow_skip, sc.margin, units)
    first = folds[0]
    seconds = {k: float(sum(f["seconds"].get(k, 0.0) for f in folds))
               for k in ("init", "stage1", "restorer", "continue", "refine") if k in first["seconds"]}
    record = {
        "decision": decision,
        "held_back_camera": first["held_back_camera"],
        "fold_cameras": first["fold_cameras"],
        "held_back_name": first["held_back_name"],
        "fold_names": first["fold_names"],
        "held_back_names": [f["held_back_name"] for f in folds],
        "scale": sc.scale,
        "frames": first["frames"],
        "psnr": psnr,
        "psnr_frames": first["psnr_frames"],
        "gain_unit": "frame" if len(folds) == 1 else "fold",
        "gain_refine_db": psnr["refine"] - psnr["skip"],
        "gain_continue_db": psnr["continue"] - psnr["skip"] if "continue" in psnr else None,
        "gains": gains(units) if len(units) == len(psnr) else {},
        "settings": {"lambda_gen": config.stage2.lambda_gen, "pseudo_mask": config.stage2.pseudo_mask,
                     "stage2_iterations": config.stage2.total_iterations, "restorer": config.restorer.kind,
                     "tie_db": sc.tie_db, "allow_skip": sc.allow_skip, "allow_continue": sc.allow_continue,
                     "margin": sc.margin, "cameras": len(folds)},
        "seconds": seconds,
        "reason": _reason(decision, psnr, sc.tie_db if sc.margin == "fixed" else None),
        **({"folds": folds} if len(folds) > 1 else {}),
    }
    atomic.write_json(out_dir / DECISION_FILE, record)
    log.info("stage-2 self-check on train camera(s) %s: %s", record["held_back_names"], record["reason"])
    return record


def fold_views(scene, config, held: int):
    """The fold's view of ``scene``: its train cameras but ``held``, at the check's scale, and
    only their frames readable."""
    from fixer4d.scene.train_view import TrainOnlyView

    fold_ids = [i for i in scene.train_ids if i != held]
    return TrainOnlyView(scene, fold_ids, config.self_check.scale, readable=fold_ids)


def fold_stage1_config(config, progress: bool = False):
    """The TrainingConfig of the fold's stage 1 (``self_check.fold_training``, ``fold_fields``)."""
    return dataclasses.replace(config.self_check.fold_training(config.training), fields=fold_fields(config),
                               progress=progress)


def _load_init(init_dir: Path):
    from fixer4d.init import load_frame_clouds
    from fixer4d.init.decompose import DecomposedInit, has_decomposed

    return DecomposedInit.load(init_dir) if has_decomposed(init_dir) else load_frame_clouds(init_dir)


def _fold_trainer(config, cfg1, views, init, field: int, directory: Path):
    """Field ``field``'s untrained trainer of the fold's stage 1 (``cfg1``: ``fold_stage1_config``)."""
    from fixer4d.model.camera_response import CameraResponse
    from fixer4d.train.fields import field_seed
    from fixer4d.train.model_init import model_from_init
    from fixer4d.train.trainer import Trainer

    cfg = dataclasses.replace(cfg1, seed=field_seed(cfg1.seed, field))
    model, terms_decision = model_from_init(init, views, cfg, config.model_terms)
    response = (CameraResponse(len(views.train_ids))
                if terms_decision is not None and terms_decision.camera_response else None)
    return Trainer(model, views, cfg, run_dir=directory, terms=config.model_terms if terms_decision is not None else None,
                   camera_response=response, depth_init=init)


def fold_field_trainer(config: dict[str, Any], held: int, init_dir: str, field: int, directory: Path):
    """Field ``field`` of the fold that holds back ``held``, built in a worker process
    (``train.field_workers``): the run's scene loaded again from ``config`` and seen as the
    pipeline's train view, the fold's finished init read back from ``init_dir``."""
    from fixer4d.pipeline.config import RunConfig
    from fixer4d.pipeline.run_folder import load_scene_for
    from fixer4d.scene.train_view import TrainOnlyView

    run_config = RunConfig.from_dict(config)
    views = fold_views(TrainOnlyView(load_scene_for(run_config)), run_config, held)
    return _fold_trainer(run_config, fold_stage1_config(run_config), views, _load_init(Path(init_dir)), field, directory)


def _run_fold(scene, config, out_dir: Path, held: int, restorer, progress: bool,
              scene_from_config: bool = False) -> dict[str, Any]:
    """One fold of the check: train camera ``held`` held back, the others trained on (init,
    stage 1, the fold's learned restorer, the continue and refine candidates); working files in
    ``out_dir``. Returns {"held_back_camera", "held_back_name", "fold_cameras", "fold_names",
    "frames", "psnr": {candidate: dB}, "psnr_frames": {candidate: [dB per frame]}, "seconds"}."""
    import json

    from fixer4d import atomic
    from fixer4d.init import run_init
    from fixer4d.model.camera_response import CameraResponse
    from fixer4d.model.io import load_ply, save_ply
    from fixer4d.pipeline.keys import stage2_key
    from fixer4d.pipeline.restoration import make_refresh_callback
    from fixer4d.restore.cache import RestoreCache
    from fixer4d.scene.train_view import TrainOnlyView
    from fixer4d.train.background import resolve_background
    from fixer4d.train.config import matched_config
    from fixer4d.train.field_workers import plan_workers
    from fixer4d.train.fields import merged_training, train_fields
    from fixer4d.train.trainer import Trainer

    sc = config.self_check
    out_dir.mkdir(parents=True, exist_ok=True)
    parts = _Parts(out_dir)
    # every part of the fold reads its own cameras only; the held-back camera's frames are read
    # through ``scored``, by ``_held_back_psnr`` alone
    views = fold_views(scene, config, held)
    scored = TrainOnlyView(scene, views.train_ids, sc.scale)
    init_dir = out_dir / "init"
    if "init" not in parts.seconds:
        t0 = time.perf_counter()
        frames = list(range(0, scene.num_frames, config.init_frame_stride))
        run_init(views, config.init.method, init_dir, frames=frames, config=config.init, progress=False)
        parts.finish("init", time.perf_counter() - t0)

    cfg1 = fold_stage1_config(config, progress)
    if "stage1" not in parts.seconds:
        init = _load_init(init_dir)

        def make_trainer(k: int, directory: Path) -> Trainer:
            return _fold_trainer(config, cfg1, views, init, k, directory)

        if cfg1.fields > 1:  # the run's stage 1 as fields merged: the fold's too
            t0 = time.perf_counter()
            recipe, workers = plan_workers(cfg1, cfg1.fields, scene_from_config,
                                           "fixer4d.pipeline.self_check_run:fold_field_trainer", config.to_dict(),
                                           held, str(init_dir))
            fields = train_fields(make_trainer, cfg1.fields, out_dir / "stage1", label="self-check fold",
                                  recipe=recipe, workers=workers, progress=progress)
            model, response = fields.model, fields.response
            seconds = time.perf_counter() - t0 + fields.prior_seconds
            shutil.rmtree(out_dir / "stage1", ignore_errors=True)
        else:
            trainer = make_trainer(0, out_dir / "stage1")
            model, seconds = _train(trainer, progress)
            response = trainer.response
        save_ply(model, out_dir / FOLD_MODEL)
        atomic.write_json(out_dir / FOLD_RESPONSE, None if response is None else response.to_json())
        parts.finish("stage1", seconds)
        del init, model
    # every part continues from the model as stored, so a resumed check starts where an
    # uninterrupted one did
    base = load_ply(out_dir / FOLD_MODEL)
    saved_response = json.loads((out_dir / FOLD_RESPONSE).read_text())
    response = None if saved_response is None else CameraResponse.from_json(saved_response)
    eval_frames = sorted({int(round(x)) for x in np.linspace(0, scene.num_frames - 1, sc.eval_frames)})
    background = torch.tensor(resolve_background(cfg1.background, views), dtype=torch.float32)
    backend = cfg1.backend
    if "skip" not in parts.psnr:
        parts.finish("skip", frames=_held_back_psnr(base, scored, held, eval_frames, backend, background))
    if config.restorer.kind == "learned":  # the run's restorer learned from the held-back camera's frames
        restorer = _fold_restorer(views, init_dir, cfg1, base, out_dir, config, parts, progress)

    def candidate(name: str, trainer) -> None:
        """Train a candidate from the fold's model, score the held-back camera, record both."""
        model, seconds = _train(trainer, progress)
        t0 = time.perf_counter()
        score = _held_back_psnr(model, scored, held, eval_frames, backend, background)
        parts.finish(name, seconds + time.perf_counter() - t0, frames=score)

    refine_cfg = merged_training(cfg1)  # the candidates continue the fold's merged model
    if sc.allow_continue and "continue" not in parts.psnr:
        candidate("continue", Trainer(copy.deepcopy(base), views, matched_config(refine_cfg, config.stage2),
                                      run_dir=out_dir / "continue", camera_response=copy.deepcopy(response)))
    if "refine" not in parts.psnr:
        refresh = make_refresh_callback(out_dir, views, config, progress=progress, backend=backend, restorer=restorer)
        candidate("refine", Trainer(copy.deepcopy(base), views, refine_cfg, stage2=config.stage2,
                                    run_dir=out_dir / "refine",
                                    cache=RestoreCache(out_dir / "cache", fingerprint=stage2_key(config)),
                                    refresh_cache=refresh, camera_response=copy.deepcopy(response)))

    psnr = {c: parts.psnr[c] for c in sc.candidates()}
    return {
        "held_back_camera": int(held),
        "held_back_name": scene.cameras[int(held)].name,
        "fold_cameras": [int(i) for i in views.train_ids],
        "fold_names": [scene.cameras[int(i)].name for i in views.train_ids],
        "frames": eval_frames,
        "psnr": psnr,
        "psnr_frames": {c: parts.frames[c] for c in psnr if c in parts.frames},  # absent in a fold from before they were kept
        "seconds": {k: parts.seconds[k] for k in ("init", "stage1", "restorer", "continue", "refine")
                    if k in parts.seconds},
    }


def _reason(decision: str, psnr: dict[str, float], tie_db: float | None) -> str:
    figures = ", ".join(f"{k} {v:.2f} dB" for k, v in psnr.items())
    margin = f"{tie_db:g} dB" if tie_db is not None else "its measured margin"
    control = "continue" in psnr
    what = {"skip": (f"no more training: neither stage 2 nor the longer control raised the held-back camera by "
                     f"more than {margin}" if control else
                     f"no more training: stage 2 did not raise the held-back camera by more than {margin}"),
            "continue": "more training on the observed views, without pseudo-views: the pseudo-loss did not pay",
            "refine": ("stage 2 with pseudo-views: it beat the same amount of plain training on the held-back camera"
                       if control else "stage 2 with pseudo-views: it raised the held-back camera")}[decision]
    return f"{decision} ({what}; held-back train camera: {figures})"


__all__ = ["run_self_check"]
