"""Training pairs for the learned restorer, from the scene's own train cameras, and its training.

    restorer = train_scene_restorer(scene, clouds, training_config, run_dir / "restorer", RestoreConfig(kind="learned"))

Pairs (in the spirit of Difix3D+ / 3DGS-Enhancer and of FVS / Deep Blending): for each
train camera c, a short stage 1 (``loo_iterations`` at ``loo_scale`` of the resolution) on the
*other* train cameras. At ``pair_frames`` timestamps:

* leave-one-out case: the render of c from that model (a model that never saw c; rendered at
  full resolution, like the clips the restorer will repair) is the degraded
  input, c's real frame the target; the references are the two train cameras nearest to c, the
  remaining one is an extra view;
* milder cases: at the ``early_fraction`` checkpoint of the same training, the renders of the
  cameras it trains on, against their real frames (references: the two nearest other train
  cameras);
* the mildest cases, when the run's stage-1 model is given: its renders of the train cameras
  (``seen_samples``). Without them the restorer only ever sees renders far worse than the ones
  stage 2 gives it and leans on the references too much: on the demo, Restoration (init) was
  23.36 dB without them and 23.83 dB with them (warp restorer 23.43 dB, STGS w/ MVS 23.46 dB).

Every camera used is one of ``scene.train_ids`` (``TrainOnlyView`` raises ``HeldOutAccess`` for any
other camera); held-out cameras are never read. The fold of train camera
``train_ids[validation_fold]`` is held back from training; its leave-one-out pairs score the
restorer (PSNR of the render, the warp restorer and the learned restorer vs the real frame) in
``validation.json`` with the CPU seconds spent. Each fold's pairs are saved as they are made
(``pairs/fold_<cam>.npz``), so a killed run resumes after its last finished fold.
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import torch

from fixer4d.atomic import atomic_path, write_json
from fixer4d.errors import InputError
from fixer4d.eval.metrics import psnr
from fixer4d.geometry.camera import Camera
from fixer4d.render.views import render_views
from fixer4d.restore.base import RestoreRequest
from fixer4d.restore.config import META_FILE, VALIDATION_FILE, WEIGHTS_FILE, RestoreConfig
from fixer4d.restore.learned import LearnedRestorer, request_features, restore_features, train_network
from fixer4d.restore.reference_warp import ReferenceWarpRestorer
from fixer4d.scene.base import MultiViewVideo
from fixer4d.scene.train_view import TrainOnlyView
from fixer4d.train.background import resolve_background
from fixer4d.train.config import SCHEDULE_KEYS, TrainingConfig
from fixer4d.train.model_init import model_from_clouds, model_from_init
from fixer4d.train.trainer import Trainer

log = logging.getLogger("fixer4d.train")

PAIRS_FORMAT = 2
# Stage-1 fields that ``TrainingConfig.for_iterations`` derives from the iteration count (the
# leave-one-out trainings get their own short schedule) or that do not change a result.
_SCHEDULE_FIELDS = ("iterations", *SCHEDULE_KEYS, "progress")
# Cap of the validation PSNRs (MSE 1e-12): validation.json cannot hold the inf of a perfect restoration.
_REPORT_MAX_DB = 120.0


def _render(model, cam: Camera, t: float, backend: str, background) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(rgb (H, W, 3), depth (H, W), alpha (H, W)) float32 host arrays of ``model`` at ``cam``, time t."""
    rgb, depth, alpha = render_views(model, [cam], t, backend, background)
    return rgb[0], depth[0], alpha[0]


def _nearest(views: TrainOnlyView, target: int, candidates: Sequence[int]) -> list[int]:
    c = views.cameras[target].center
    return sorted(candidates, key=lambda i: (float(np.linalg.norm(views.cameras[i].center - c)), i))


def pair_request(model, views: TrainOnlyView, target: int, frame: int, backend: str, background) -> RestoreRequest:
    """A one-frame request at train camera ``target`` with references and extras from the other train cameras."""
    others = _nearest(views, target, [i for i in views.readable_ids if i != target])
    if len(others) < 2:
        raise InputError("restorer pairs: need at least 3 train cameras (a target and two references)")
    refs, extras = others[:2], others[2:]
    t = views.time(frame)
    cam = views.cameras[target]
    rgb, depth, alpha = _render(model, cam, t, backend, background)
    ref_r = [_render(model, views.cameras[i], t, backend, background) for i in refs]
    ext_r = [_render(model, views.cameras[i], t, backend, background) for i in extras]
    return RestoreRequest(
        rgb=rgb[None], depth=depth[None], alpha=alpha[None], cameras=[cam], time=t, frame=frame,
        ref_images=[views.frame(frame, i) for i in refs], ref_cameras=[views.cameras[i] for i in refs],
        ref_depths=[r[1] for r in ref_r], ref_alphas=[r[2] for r in ref_r],
        extra_images=[views.frame(frame, i) for i in extras] or None,
        extra_cameras=[views.cameras[i] for i in extras] or None, extra_depths=[r[1] for r in ext_r] or None,
        trajectory={"name": f"pair-target-{target}", "target": int(target)})


def _init_model(init: Any, views: TrainOnlyView, cfg: TrainingConfig):
    """The leave-one-out model from the run's init: per-frame clouds, or a decomposed init
    (static + moving parts, fixer4d.init.decompose) built with the default model terms."""
    if isinstance(init, (list, tuple)):
        return model_from_clouds(list(init), views, cfg)
    return model_from_init(init, views, cfg)[0]


def _loo_config(training: TrainingConfig, iterations: int) -> TrainingConfig:
    keep = {k: v for k, v in training.to_dict().items() if k not in _SCHEDULE_FIELDS}
    return TrainingConfig.for_iterations(iterations, **keep, progress=False)


def pair_frames(num_frames: int, count: int) -> list[int]:
    """``count`` timestamps spread evenly over the video (unique, sorted)."""
    return sorted({int(round(x)) for x in np.linspace(0, num_frames - 1, max(1, count))})


def fold_trainer(scene: MultiViewVideo, clouds: Sequence[Any], training: TrainingConfig, left_out: int,
                 config: RestoreConfig) -> tuple[Trainer, TrainOnlyView]:
    """The leave-one-out training of the fold leaving out train camera ``left_out``, not yet
    stepped (``loo_iterations`` at ``loo_scale``), and the other train cameras at full resolution:
    the model trains at loo_scale but its pairs are rendered at full resolution, so the restorer
    learns on the image statistics (blur widths, hole sizes in pixels) it will restore."""
    if left_out not in scene.train_ids:
        raise InputError(f"restorer pairs: camera {left_out} is not a train camera of {scene.name}")
    lc = config.learned
    trained = [i for i in scene.train_ids if i != left_out]
    views = TrainOnlyView(scene, trained, lc.loo_scale)
    cfg = _loo_config(training, lc.loo_iterations)
    trainer = Trainer(_init_model(clouds, views, cfg), views, cfg, run_dir=None)
    return trainer, (TrainOnlyView(scene, trained, 1.0) if lc.loo_scale != 1.0 else views)


def build_fold(scene: MultiViewVideo, clouds: Sequence[Any], training: TrainingConfig, left_out: int,
               config: RestoreConfig, progress: bool = False) -> dict[str, np.ndarray]:
    """The pairs of the fold leaving out train camera ``left_out``: arrays feats (N, C, H, W)
    float16, targets (N, H, W, 3) float16, cams (N,), frames (N,), loo (N,) bool (True = the
    left-out camera's render, False = an early-checkpoint render of a trained camera)."""
    lc = config.learned
    trainer, full = fold_trainer(scene, clouds, training, left_out, config)
    trained = [i for i in scene.train_ids if i != left_out]
    warp = ReferenceWarpRestorer(config.warp)
    frames = pair_frames(scene.num_frames, lc.pair_frames)
    backend, background = trainer.config.backend, trainer.background
    samples: list[tuple[np.ndarray, np.ndarray, int, int, bool]] = []

    def add(target: int, loo: bool) -> None:
        for f in frames:
            req = pair_request(trainer.model, full, target, f, backend, background)
            feats, _ = request_features(req, warp)
            samples.append((feats[0], full.frame(f, target), target, f, loo))

    trainer.train(max(1, int(round(lc.early_fraction * trainer.config.iterations))), progress=progress)
    for cam in trained:
        add(cam, False)
    trainer.train(progress=progress)
    add(left_out, True)
    return {"feats": np.stack([s[0] for s in samples]).astype(np.float16),
            "targets": np.stack([s[1] for s in samples]).astype(np.float16),
            "cams": np.array([s[2] for s in samples], np.int64), "frames": np.array([s[3] for s in samples], np.int64),
            "loo": np.array([s[4] for s in samples], bool)}


def _init_digest(init: Any) -> str:
    """SHA-1 of the arrays an init is made of (per-frame clouds, or the fields of a decomposed init)."""
    h = hashlib.sha1()

    def feed(value: Any) -> None:
        if isinstance(value, np.ndarray):
            h.update(str((value.dtype, value.shape)).encode())
            h.update(np.ascontiguousarray(value).tobytes())
        elif isinstance(value, (list, tuple)):
            for v in value:
                feed(v)
        elif isinstance(value, (int, float, str, bool)):
            h.update(repr(value).encode())
        elif hasattr(value, "__dict__"):
            for k in sorted(vars(value)):
                feed(vars(value)[k])

    feed(init)
    return h.hexdigest()[:16]


def _key(scene: MultiViewVideo, init: Any, training: TrainingConfig, config: RestoreConfig) -> str:
    parts = {"format": PAIRS_FORMAT, "scene": scene.describe(), "train_ids": list(scene.train_ids),
             "init": _init_digest(init),
             "stage1": {k: v for k, v in training.to_dict().items() if k not in _SCHEDULE_FIELDS},
             "warp": dataclasses.asdict(config.warp), "learned": config.learned.training_key()}
    return hashlib.sha1(json.dumps(parts, sort_keys=True, default=str).encode()).hexdigest()[:16]


def seen_samples(model, scene: MultiViewVideo, config: RestoreConfig, background) -> dict[str, np.ndarray]:
    """Pairs from a model that saw every train camera (the run's stage-1 model): its render of each
    train camera against the real frame, the other train cameras as references. The mildest cases,
    like the renders stage 2 restores near the train cameras; same arrays as ``build_fold``."""
    views = TrainOnlyView(scene, scene.train_ids, 1.0)
    warp = ReferenceWarpRestorer(config.warp)
    rows = []
    for cam in scene.train_ids:
        for f in pair_frames(scene.num_frames, config.learned.pair_frames):
            feats, _ = request_features(pair_request(model, views, cam, f, "auto", background), warp)
            rows.append((feats[0], views.frame(f, cam), cam, f))
    return {"feats": np.stack([r[0] for r in rows]).astype(np.float16),
            "targets": np.stack([r[1] for r in rows]).astype(np.float16),
            "cams": np.array([r[2] for r in rows], np.int64), "frames": np.array([r[3] for r in rows], np.int64),
            "loo": np.zeros(len(rows), bool)}


def _fold_pairs(scene: MultiViewVideo, clouds: Sequence[Any], training: TrainingConfig, config: RestoreConfig,
                out_dir: Path, key: str, progress: bool) -> tuple[dict[int, dict[str, np.ndarray]], float]:
    """{train camera: its fold's pairs (``build_fold``)} and the CPU seconds they cost: a fold saved
    in ``out_dir``/pairs under the same ``key`` is read back, any other is built and saved."""
    folds: dict[int, dict[str, np.ndarray]] = {}
    pair_cpu = 0.0
    for cam in scene.train_ids:
        path = out_dir / "pairs" / f"fold_{cam}.npz"
        key_path = path.with_suffix(".json")
        if path.is_file() and key_path.is_file() and json.loads(key_path.read_text()).get("key") == key:
            with np.load(path, allow_pickle=False) as data:
                folds[cam] = {k: np.array(data[k]) for k in data.files}
            pair_cpu += float(json.loads(key_path.read_text()).get("cpu_seconds", 0.0))
            continue
        if progress:
            print(f"[fixer4d] learned restorer: leave-one-out fold without camera {cam}", flush=True)
        c0 = time.process_time()
        folds[cam] = build_fold(scene, clouds, training, cam, config, progress=progress)
        with atomic_path(path, suffix=".npz") as tmp:
            np.savez_compressed(tmp, **folds[cam])
        pair_cpu += time.process_time() - c0
        write_json(key_path, {"key": key, "cpu_seconds": time.process_time() - c0})
    return folds, pair_cpu


def _fold_samples(folds: dict[int, dict[str, np.ndarray]], cams: Sequence[int],
                  loo_only: bool = False) -> list[tuple[np.ndarray, np.ndarray]]:
    """(features (C, H, W), target (H, W, 3)) float32 pairs of the folds of ``cams``; ``loo_only``:
    the left-out camera's renders only."""
    out = []
    for cam in cams:
        d = folds[cam]
        for n in range(len(d["cams"])):
            if loo_only and not d["loo"][n]:
                continue
            out.append((d["feats"][n].astype(np.float32), d["targets"][n].astype(np.float32)))
    return out


def _validation_psnrs(net, val: Sequence[tuple[np.ndarray, np.ndarray]]) -> dict[str, list[float]]:
    """PSNR (dB) vs the real frame of each validation pair's render, warp restoration and learned
    restoration (features 0:3 and 12:15 are the render and the warp, ``request_features``)."""
    scores: dict[str, list[float]] = {"render": [], "warp": [], "learned": []}
    for feats, target in val:
        restored, _ = restore_features(net, feats)
        scores["render"].append(psnr(feats[0:3].transpose(1, 2, 0), target, max_db=_REPORT_MAX_DB))
        scores["warp"].append(psnr(feats[12:15].transpose(1, 2, 0), target, max_db=_REPORT_MAX_DB))
        scores["learned"].append(psnr(restored, target, max_db=_REPORT_MAX_DB))
    return scores


def train_scene_restorer(scene: MultiViewVideo, clouds: Sequence[Any], training: TrainingConfig, out_dir: str | Path,
                         config: RestoreConfig, progress: bool = True, model=None) -> LearnedRestorer:
    """Build the leave-one-camera-out pairs, train the learned restorer, validate it on the held-back
    fold; returns it. Writes into ``out_dir``: pairs/fold_<cam>.npz (+ key), WEIGHTS_FILE,
    META_FILE and VALIDATION_FILE (validation gain and CPU seconds). Resumes: finished folds are
    reused, and finished weights with the same settings are loaded instead of retrained.
    clouds: the init's per-frame point clouds (``model_from_clouds`` input). model: the run's
    stage-1 model (trained on every train camera), whose renders of the train cameras are added as
    the mildest pairs (``seen_samples``; the held-back camera's are left out), or None."""
    out_dir = Path(out_dir)
    key = _key(scene, clouds, training, config)
    weights_key = key if model is None else hashlib.sha1(
        (key + _init_digest([v.detach().cpu().numpy() for v in model.state_dict().values()])).encode()).hexdigest()[:16]
    if (out_dir / WEIGHTS_FILE).is_file() and (out_dir / VALIDATION_FILE).is_file():
        meta = json.loads((out_dir / META_FILE).read_text()) if (out_dir / META_FILE).is_file() else {}
        if meta.get("pairs_key") == weights_key:
            return LearnedRestorer.load(out_dir, config)
    lc = config.learned
    train_ids = list(scene.train_ids)
    if len(train_ids) < 3:
        raise InputError(f"{scene.name}: the learned restorer needs >= 3 train cameras (has {len(train_ids)}); "
                         "use --restorer warp")
    held = train_ids[lc.validation_fold % len(train_ids)]
    cpu0, wall0 = time.process_time(), time.perf_counter()
    folds, pair_cpu = _fold_pairs(scene, clouds, training, config, out_dir, key, progress)
    seen = None
    if model is not None:
        c0 = time.process_time()
        with torch.no_grad():
            seen = seen_samples(model, scene, config, torch.tensor(resolve_background(training.background, scene),
                                                                    dtype=torch.float32))
        pair_cpu += time.process_time() - c0

    train_set = _fold_samples(folds, [c for c in train_ids if c != held])
    if seen is not None:  # the stage-1 model's renders of the train cameras, the held-back one excepted
        train_set += [(seen["feats"][n].astype(np.float32), seen["targets"][n].astype(np.float32))
                      for n in range(len(seen["cams"])) if seen["cams"][n] != held]
    if progress:
        print(f"[fixer4d] learned restorer: training on {len(train_set)} pairs ({lc.steps} steps)", flush=True)
    net, stats = train_network(train_set, lc)
    val = _fold_samples(folds, [held], loo_only=True)
    scores = _validation_psnrs(net, val)
    mean = {k: float(np.mean(v)) for k, v in scores.items()}
    validation = {
        "held_out_fold_camera": int(held), "validation_pairs": len(val), "training_pairs": len(train_set),
        "psnr_render": mean["render"], "psnr_warp": mean["warp"], "psnr_learned": mean["learned"],
        "gain_db": mean["learned"] - mean["render"], "gain_over_warp_db": mean["learned"] - mean["warp"],
        "per_pair_psnr": scores,
        "cpu_seconds": {"pairs": pair_cpu, "training": stats["cpu_seconds"],
                        "total": pair_cpu + stats["cpu_seconds"]},
        "wall_seconds_this_session": time.perf_counter() - wall0,
        "cpu_seconds_this_session": time.process_time() - cpu0,
        "network": stats, "settings": {"warp": dataclasses.asdict(config.warp), "learned": dataclasses.asdict(lc)},
    }
    restorer = LearnedRestorer(net, config)
    restorer.save(out_dir, extra={"pairs_key": weights_key, "validation_gain_db": validation["gain_db"]})
    write_json(out_dir / VALIDATION_FILE, validation)
    if progress:
        print(f"[fixer4d] learned restorer: validation (camera {held}) render {mean['render']:.2f} dB, warp "
              f"{mean['warp']:.2f} dB, learned {mean['learned']:.2f} dB; {validation['cpu_seconds']['total']:.0f} CPU s",
              flush=True)
    return restorer
