"""The stage functions every entry point calls: init -> stage 1 -> (restore -> refine) -> evaluate.

Each stage takes the run (``StageContext``: run folder, resolved config, scene) and returns its
artifact. Each is keyed by everything its output depends on (``keys``): a finished stage with the
same key is read back, a stage that was started under another key has its partial outputs (trainer
checkpoints, restoration cache) moved out of the way and is recomputed, and a study's shared
``StageCache`` serves finished outputs between runs. `fixer4d run`, `reconstruct`, `refine`, `eval`,
`study` and the viewer's live training all go through these functions.

Layout of the outputs in RUN/ (docs/design.md §6 has every file):

    init_<method>/            clouds + init_report.json
    model_stage1.ply          stage 1 from the main init ("STGS w/ MVS")
    model_stage1_twin.ply     its twin field (co_fields.enabled; train/co_fields.py)
    baseline_sparse/          stage 1 from the sparse init ("STGS w/ COLMAP")
    matched/model.ply         stage 1 continued as long as stage 2, without pseudo-views
    cache/round_<r>/          restored trajectory clips (pseudo-targets)
    model_final.ply           after stage 2 ("Full")
    eval/<slug>/              metrics.json + side-by-side PNGs per report row
"""
from __future__ import annotations

import copy
import dataclasses
import logging
import shutil
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np

from fixer4d import atomic
from fixer4d.errors import InputError
from fixer4d.geometry.camera import Camera
from fixer4d.pipeline.config import RunConfig
from fixer4d.pipeline.keys import (SELF_CHECK_DECISION_SETTINGS, field_key, init_key, matched_key, restorer_key, self_check_key,
                                   stage1_key, stage2_key)
from fixer4d.pipeline.run_folder import RunFolder, stage_key
from fixer4d.pipeline.stage_cache import StageCache

log = logging.getLogger("fixer4d.pipeline")

# The stage-1 model's terms and why (Gaussians static/dynamic, degrees, switches, revisions),
# beside the model; the report's "model" section.
TERMS_NAME = "model_terms.json"
# The same file as run folders made before the terms were called so name it: read when
# TERMS_NAME is absent (``terms_path``), never written.
FORMER_TERMS_NAME = "model_effects.json"


def terms_path(run_dir: Path) -> Path:
    """The model-terms file of ``run_dir``: TERMS_NAME, else the former name where only that
    exists (a run folder, or a stage cache entry, from before the rename)."""
    path = Path(run_dir) / TERMS_NAME
    former = Path(run_dir) / FORMER_TERMS_NAME
    return former if not path.is_file() and former.is_file() else path


class StageFailed(InputError):
    """A stage could not produce its output for a reason the report should show (e.g. the sparse
    baseline triangulated no points)."""


@dataclass
class StageContext:
    """What every stage needs: the run folder (with its config), the scene, the display and an
    optional study-wide cache."""

    run: RunFolder
    scene: Any
    progress: bool = True
    cache: StageCache | None = None
    # keep a finished stage's checkpoints (`--keep-checkpoints`); by default a stage's checkpoints
    # go once its outputs are written
    keep_checkpoints: bool = False
    # ``scene`` is ``load_scene_for(config)``, which a worker process can load again: stage 1's fields
    # and the self-check fold's may then train side by side (train.field_workers)
    scene_from_config: bool = False
    _train_scene: Any = dataclasses.field(default=None, repr=False)

    @property
    def config(self) -> RunConfig:
        return self.run.config

    @property
    def train_scene(self):
        """The scene as every stage but evaluation sees it: its train cameras only
        (``TrainOnlyView``: a held-out frame, mask or depth read raises HeldOutAccess)."""
        from fixer4d.scene.train_view import TrainOnlyView

        if self._train_scene is None:
            self._train_scene = TrainOnlyView(self.scene)
        return self._train_scene

    @property
    def path(self) -> Path:
        return self.run.path

    @property
    def backend(self) -> str:
        return self.config.training.backend

    @property
    def background(self) -> tuple[float, float, float]:
        """The RGB this run's renders use (``training.background`` resolved on its train views)."""
        from fixer4d.train.background import resolve_background

        return resolve_background(self.config.training.background, self.train_scene)

    def training_config(self, **changes: Any):
        return dataclasses.replace(self.config.training, progress=self.progress, **changes)

    def refine_training_config(self):
        """The TrainingConfig of the trainings that continue the main stage-1 model (stage 2, the
        matched control): ``train.fields.merged_training``."""
        from fixer4d.train.fields import merged_training

        return merged_training(self.training_config())


# ---------------------------------------------------------------------------------------------
# stages
# ---------------------------------------------------------------------------------------------
def init_stage(ctx: StageContext, method: str):
    """Point clouds of every ``init_frame_stride``-th frame by ``method`` (sparse | mvs) -> RUN/init_<method>/.

    Raises StageFailed when the sparse baseline finds no point at all (reported in its row)."""
    from fixer4d.init import load_frame_clouds, run_init
    from fixer4d.init.decompose import DecomposedInit, has_decomposed

    out = ctx.path / f"init_{method}"
    name = f"init_{method}"
    key = init_key(ctx.config, method)
    if not (ctx.run.records.done(name, key) and (out / "init_report.json").exists()):
        ctx.run.records.begin(name, key)
        _clear(out, keep_aside=False)
        if ctx.cache is not None and (seconds := ctx.cache.fetch(key, out)) is not None:
            ctx.run.records.finish(name, key, seconds)
        else:
            t0 = time.perf_counter()
            frames = list(range(0, ctx.scene.num_frames, ctx.config.init_frame_stride))
            cfg = dataclasses.replace(ctx.config.init, method=method)
            run_init(ctx.train_scene, method, out, frames=frames, config=cfg, progress=ctx.progress)
            ctx.run.records.finish(name, key, time.perf_counter() - t0)
            if ctx.cache is not None:
                ctx.cache.store(key, [out / p.name for p in out.iterdir()], ctx.run.records.seconds(name))
    # always the init as stored (colours are uint8 on disk), so a resumed stage 1 trains on the
    # same input as an uninterrupted one
    try:
        clouds = load_frame_clouds(out)
    except InputError:
        clouds = []
    if sum(len(c.points) for c in clouds) == 0 and method == "sparse":
        raise StageFailed(f"the sparse (COLMAP) init triangulated no points on any of its "
                          f"{len(range(0, ctx.scene.num_frames, ctx.config.init_frame_stride))} init frames")
    if has_decomposed(out):
        return DecomposedInit.load(out)
    return clouds


def stage1(ctx: StageContext, method: str, clouds, model_path: Path, name: str):
    """Stage 1 (STGS on the observed views) from ``clouds`` -> ``model_path``; resumes mid-stage.
    The main init's stage 1 trains ``training.fields`` fields and merges them (train/fields.py)."""
    from fixer4d.model.io import load_ply, save_ply
    from fixer4d.model.terms import terms_report
    from fixer4d.train.co_fields import TWIN_DIR, TWIN_NAME
    from fixer4d.train.fields import FIELDS_DIR, keep_matching_fields

    key = stage1_key(ctx.config, method)
    main = method == ctx.config.init_method
    twin = ctx.config.co_fields.enabled and main
    fields = ctx.config.training.fields if main else 1
    outputs = [model_path] + ([model_path.parent / TWIN_NAME] if twin else [])
    if ctx.run.records.done(name, key) and all(p.exists() for p in outputs):
        return load_ply(model_path)
    if ctx.run.records.begin(name, key):
        _drop_checkpoints(model_path.parent, 1)
        _drop_checkpoints(model_path.parent / TWIN_DIR, 1)
        if main:
            keep_matching_fields(model_path.parent, lambda k: field_key(ctx.config, k))
    if ctx.cache is not None and (seconds := ctx.cache.fetch(key, model_path.parent)) is not None:
        ctx.run.records.finish(name, key, seconds)
        return load_ply(model_path)
    t0 = time.perf_counter()
    if fields > 1:
        model, decision, revisions, response, prior = _stage1_fields(ctx, clouds, model_path.parent, fields)
    else:
        trainer, decision = stage1_trainer(ctx, clouds, model_path.parent, depth_prior=main)
        if twin:
            from fixer4d.train.co_fields import CoFields, twin_trainer

            co = CoFields(trainer, twin_trainer(trainer, ctx.config.model_terms if decision is not None else None,
                                                model_path.parent), ctx.config.co_fields)
            prior = co.train_seconds if co.resume() else 0.0
            co.train()
            save_ply(co.b.host_model(), outputs[1])
        else:
            prior = trainer.train_seconds if trainer.resume() else 0.0
            trainer.train()
        model, revisions, response = trainer.host_model(), trainer.revisions, trainer.response
    save_ply(model, model_path)
    report = terms_report(model, decision, revisions)
    if fields > 1:
        report["fields"] = fields
    if response is not None:
        report["camera_response"] = response.to_json()
    atomic.write_json(model_path.parent / TERMS_NAME, report)
    ctx.run.records.finish(name, key, time.perf_counter() - t0 + prior)
    _finished(ctx, model_path.parent, 1)
    _finished(ctx, model_path.parent / TWIN_DIR, 1)
    if ctx.cache is not None:
        fields_dir = [model_path.parent / FIELDS_DIR] if fields > 1 else []
        ctx.cache.store(key, outputs + [model_path.parent / TERMS_NAME] + fields_dir, ctx.run.records.seconds(name))
    return model


def _stage1_fields(ctx: StageContext, clouds, run_dir: Path, fields: int):
    """The main init's stage 1 as ``fields`` fields merged (``train.fields.train_fields``, in
    RUN/fields/). Returns (model, terms decision, revisions, camera response, seconds trained
    before this call)."""
    from fixer4d.train.field_workers import plan_workers
    from fixer4d.train.fields import train_fields

    if ctx.config.co_fields.enabled:
        raise InputError("training.fields > 1 trains stage 1's fields apart and merges them; co_fields trains a "
                         "twin beside one field: set training.fields=1 or co_fields.enabled=false")
    decisions = []

    def make_trainer(k: int, out: Path):
        trainer, decision = stage1_trainer(ctx, clouds, out, field=k)
        decisions.append(decision)
        return trainer

    recipe, workers = plan_workers(ctx.config.training, fields, ctx.scene_from_config,
                                   "fixer4d.pipeline.stages:stage1_field_trainer", ctx.config.to_dict(), str(ctx.path))
    done = train_fields(make_trainer, fields, run_dir, finished=lambda out: _finished(ctx, out, 1),
                        key=lambda k: field_key(ctx.config, k), recipe=recipe, workers=workers, progress=ctx.progress)
    if not decisions:  # every field was finished: the decision is the init's, whatever the seed
        _, decision = stage1_trainer(ctx, clouds, None)
        decisions.append(decision)
    return done.model, decisions[0], done.revisions, done.response, done.prior_seconds


def stage1_field_trainer(config: dict[str, Any], run_path: str, field: int, directory: Path):
    """Field ``field``'s stage-1 trainer in a worker process (``train.field_workers``): the run's scene
    loaded again and its finished init read back, built as ``stage1_trainer`` builds it."""
    from fixer4d.pipeline.run_folder import load_scene_for

    run_config = RunConfig.from_dict(config)
    ctx = StageContext(run=RunFolder(Path(run_path), run_config), scene=load_scene_for(run_config), progress=False)
    trainer, _ = stage1_trainer(ctx, init_stage(ctx, run_config.init_method), directory, field=field)
    return trainer


def stage1_trainer(ctx: StageContext, init, run_dir: Path | None, depth_prior: bool = True, field: int = 0):
    """(Trainer, model-terms decision) exactly as ``stage1`` builds them: the model from ``init`` (a
    decomposed init -> terms decided by evidence under ``config.model_terms``; per-frame clouds ->
    every term on), the run's TrainingConfig with its scaled schedule, term revisions during
    training. For callers that step the trainer themselves too (the viewer's live training).
    run_dir: where checkpoints go (None: none). depth_prior: ``init``'s points are depth targets
    when ``training.depth_prior`` is on (False: the sparse baseline, which stays the paper's STGS).
    field: which of ``training.fields`` this trainer trains (its seed, train/fields.py)."""
    from fixer4d.train.fields import field_seed
    from fixer4d.train.model_init import model_from_init
    from fixer4d.train.trainer import Trainer

    cfg = ctx.training_config()
    if field:
        cfg = dataclasses.replace(cfg, seed=field_seed(cfg.seed, field))
    model, decision = model_from_init(init, ctx.train_scene, cfg, ctx.config.model_terms)
    if ctx.config.segments.static_from is not None:
        from fixer4d.pipeline.shared_static import add_shared_static, load_shared

        shared = load_shared(ctx.config.segments.static_from, "stage1")
        counts = add_shared_static(model, shared, ctx.train_scene.train_cameras, backend=ctx.backend)
        if decision is not None:
            decision.reasons["shared_static"] = (
                f"{counts['shared_static']} frozen static Gaussians of the first segment; own static points kept "
                f"where they are not explained by them: {counts['own_static_kept']} kept, "
                f"{counts['own_static_dropped']} dropped")
    response = None
    if decision is not None and decision.camera_response:
        from fixer4d.model.camera_response import CameraResponse

        response = CameraResponse(len(ctx.train_scene.train_ids))
    trainer = Trainer(model, ctx.train_scene, cfg, run_dir=run_dir,
                      terms=ctx.config.model_terms if decision is not None else None, camera_response=response,
                      depth_init=init if depth_prior else None)
    return trainer, decision


def stage1_response(ctx: StageContext):
    """The camera response stage 1 trained (RUN/model_terms.json), to continue from in stage 2
    and the matched control; None when the scene's cameras agree on colour."""
    import json

    from fixer4d.model.camera_response import CameraResponse

    path = terms_path(ctx.path)
    saved = json.loads(path.read_text()).get("camera_response") if path.is_file() else None
    return None if saved is None else CameraResponse.from_json(saved)


def restorer_stage(ctx: StageContext, clouds, model):
    """The run's restorer; the learned one is first trained on the scene's own train cameras
    (leave-one-camera-out trainings from ``clouds``, plus the stage-1 ``model``'s renders of the
    train cameras as the mildest pairs; ``train_scene_restorer``) into RUN/restorer/ (resumable:
    finished folds are reused). Other kinds are built as they are (no stage record)."""
    from fixer4d.pipeline.restoration import RESTORER_DIR, run_restorer

    rc = ctx.config.restorer
    if rc.kind != "learned":
        return run_restorer(ctx.config, ctx.path)
    from fixer4d.train.restorer_pairs import train_scene_restorer

    key = restorer_key(ctx.config)
    if ctx.run.records.done("restorer", key):
        return run_restorer(ctx.config, ctx.path)
    if ctx.run.records.begin("restorer", key):
        _clear(ctx.path / RESTORER_DIR)
    t0 = time.perf_counter()
    restorer = train_scene_restorer(ctx.train_scene, clouds, ctx.training_config(), ctx.path / RESTORER_DIR, rc,
                                    progress=ctx.progress, model=model)
    ctx.run.records.finish("restorer", key, time.perf_counter() - t0)
    return restorer


def restorer_summary(ctx: StageContext) -> dict[str, Any]:
    """{"kind", "validation"?}: what the report says about the restorer (the learned one's own
    leave-one-camera-out validation: render vs restored PSNR on the held-back train camera)."""
    import json

    from fixer4d.pipeline.restoration import RESTORER_DIR
    from fixer4d.restore.config import VALIDATION_FILE

    out: dict[str, Any] = {"kind": ctx.config.restorer.kind}
    val = ctx.path / RESTORER_DIR / VALIDATION_FILE
    if ctx.config.restorer.kind == "learned" and val.is_file():
        v = json.loads(val.read_text())
        out["validation"] = {k: v[k] for k in ("held_out_fold_camera", "psnr_render", "psnr_warp", "psnr_learned",
                                               "gain_db", "gain_over_warp_db", "cpu_seconds") if k in v}
    return out


# A field's own stage 2 and matched control, when they continue the fields apart: RUN/fields/field<k>/<dir>/
STAGE2_DIR = "stage2"
MATCHED_DIR = "matched"


def refines_apart(ctx: StageContext) -> bool:
    """Stage 2 and the matched control continue each of stage 1's fields apart (``stage2.fields``)."""
    from fixer4d.train.fields import refined_apart

    return refined_apart(ctx.config.training, ctx.config.stage2)


def field_refine_configs(ctx: StageContext, field: int):
    """(TrainingConfig, Stage2Config) of field ``field``'s own continuation: one field's budget,
    the field's seeds (``train.fields.field_seed``) for training and for stage 2's draws."""
    from fixer4d.train.fields import field_seed

    cfg = ctx.training_config()
    return (dataclasses.replace(cfg, seed=field_seed(cfg.seed, field)),
            dataclasses.replace(ctx.config.stage2, seed=field_seed(ctx.config.stage2.seed, field)))


def stage2(ctx: StageContext, model, refresh: Callable[[Any, int], None] | None = None):
    """Restoration-guided refinement of the stage-1 ``model`` -> RUN/model_final.ply.

    refresh: the cache refresh (default: the pipeline's, restoring the configured trajectories).
    With ``stage2.fields=apart`` each of stage 1's fields is refined on its own (RUN/fields/
    field<k>/stage2/; field 0's pseudo-targets in RUN/cache) and the refined fields are merged.
    When the stage's settings changed since an earlier attempt, that attempt's cache and
    checkpoints are moved aside (RUN/stale/) so no stale pseudo-target is reused."""
    from fixer4d.model.io import load_ply, save_ply
    from fixer4d.pipeline.restoration import make_refresh_callback, twin_weight_for
    from fixer4d.restore.cache import RestoreCache
    from fixer4d.train.fields import field_dir, load_field, train_fields
    from fixer4d.train.trainer import Trainer

    if refines_apart(ctx) and (refresh is not None or ctx.config.segments.static_from is not None):
        raise InputError("stage2.fields=apart refines stage 1's fields one by one; a given cache refresh or a segment "
                         "sharing another's static Gaussians (segments.static_from) refines the merged model: set "
                         "stage2.fields=merged")
    final = ctx.path / "model_final.ply"
    key = stage2_key(ctx.config)
    if ctx.run.records.done("stage2", key) and final.exists():
        return load_ply(final)
    if ctx.run.records.begin("stage2", key):
        _clear(ctx.path / "cache")
        _drop_checkpoints(ctx.path, 2)
        for k in range(ctx.config.training.fields):
            _clear(field_dir(ctx.path, k, STAGE2_DIR), keep_aside=False)
    t0 = time.perf_counter()
    if ctx.config.segments.static_from is not None:  # beside the first segment's refined static rows
        from fixer4d.pipeline.shared_static import load_shared, swap_shared_static

        model = swap_shared_static(model, load_shared(ctx.config.segments.static_from, "final"))
    def refresh_for(cache_dir: Path, restorer=None):
        from fixer4d.pipeline.executors import executor_for

        return make_refresh_callback(cache_dir, ctx.train_scene, ctx.config, progress=ctx.progress, backend=ctx.backend,
                                     executor=executor_for(ctx.config.executor), restorer=restorer,
                                     twin=twin_weight_for(ctx.config, ctx.path))
    if refines_apart(ctx):
        from fixer4d.pipeline.restoration import run_restorer

        restorer = run_restorer(ctx.config, ctx.path)

        def make_trainer(k: int, out: Path):
            field_model, response = load_field(ctx.path, k)
            cfg, stage2_cfg = field_refine_configs(ctx, k)
            # field 0's pseudo-targets are the run's cache (RUN/cache, what the viewer shows)
            cache_dir = ctx.path if k == 0 else out
            return Trainer(field_model, ctx.train_scene, cfg, run_dir=out, stage2=stage2_cfg,
                           cache=RestoreCache(cache_dir / "cache", fingerprint=key),
                           refresh_cache=refresh_for(cache_dir, restorer), camera_response=response)

        done = train_fields(make_trainer, ctx.config.training.fields, ctx.path, label="stage 2", step=STAGE2_DIR,
                            finished=lambda out: _finished(ctx, out, 2))
        model, prior = done.model, done.prior_seconds
    else:
        trainer = Trainer(model, ctx.train_scene, ctx.refine_training_config(), run_dir=ctx.path,
                          stage2=ctx.config.stage2, cache=RestoreCache(ctx.path / "cache", fingerprint=key),
                          refresh_cache=refresh or refresh_for(ctx.path), camera_response=stage1_response(ctx))
        prior = trainer.train_seconds if trainer.resume() else 0.0
        trainer.train()
        model = trainer.host_model()
    save_ply(model, final)
    ctx.run.records.finish("stage2", key, time.perf_counter() - t0 + prior)
    _finished(ctx, ctx.path, 2)
    return model


def matched_stage1(ctx: StageContext, model):
    """Stage 1 continued for as many iterations as stage 2 runs, with stage 2's learning rates and
    densification window but no pseudo-views -> RUN/matched/model.ply: the control that shows the
    gain of stage 2 is the restorer's, not extra training."""
    from fixer4d.model.io import load_ply, save_ply
    from fixer4d.train.config import matched_config
    from fixer4d.train.fields import field_dir, load_field, train_fields
    from fixer4d.train.trainer import Trainer

    out = ctx.path / "matched"
    path = out / "model.ply"
    key = matched_key(ctx.config)
    if ctx.run.records.done("matched", key) and path.exists():
        return load_ply(path)
    if ctx.run.records.begin("matched", key):
        _drop_checkpoints(out, 1)
        for k in range(ctx.config.training.fields):
            _clear(field_dir(ctx.path, k, MATCHED_DIR), keep_aside=False)
    t0 = time.perf_counter()
    if refines_apart(ctx):
        def make_trainer(k: int, directory: Path):
            field_model, response = load_field(ctx.path, k)
            cfg, stage2_cfg = field_refine_configs(ctx, k)
            return Trainer(field_model, ctx.train_scene, matched_config(cfg, stage2_cfg), run_dir=directory,
                           camera_response=response)

        done = train_fields(make_trainer, ctx.config.training.fields, ctx.path, label="matched control",
                            step=MATCHED_DIR, finished=lambda directory: _finished(ctx, directory, 1))
        model, prior = done.model, done.prior_seconds
    else:
        cfg = matched_config(ctx.refine_training_config(), ctx.config.stage2)
        # a copy: the Trainer updates its model in place, and stage 2 must start from the stage-1 model
        trainer = Trainer(copy.deepcopy(model), ctx.train_scene, cfg, run_dir=out, camera_response=stage1_response(ctx))
        prior = trainer.train_seconds if trainer.resume() else 0.0
        trainer.train()
        model = trainer.host_model()
    save_ply(model, path)
    ctx.run.records.finish("matched", key, time.perf_counter() - t0 + prior)
    _finished(ctx, out, 1)
    return model


def self_check_stage(ctx: StageContext, restorer) -> dict[str, Any]:
    """The stage-2 self-check (``pipeline.self_check``) -> RUN/self_check/decision.json; its
    ``decision`` (skip | continue | refine) chooses the run's final model. Disabled: refine. A
    killed check resumes under the same settings (``self_check_run.run_self_check``)."""
    import json

    from fixer4d.pipeline.self_check import DECISION_FILE
    from fixer4d.pipeline.self_check_run import run_self_check

    sc = ctx.config.self_check
    if not sc.enabled:
        return {"decision": "refine", "enabled": False,
                "reason": "self-check off (self_check.enabled=false): stage 2 as configured"}
    out = ctx.path / "self_check"
    key = self_check_key(ctx.config)
    if ctx.run.records.done("self_check", key) and (out / DECISION_FILE).is_file():
        record = json.loads((out / DECISION_FILE).read_text())
        if all(record.get("settings", {}).get(k) == getattr(sc, k) for k in SELF_CHECK_DECISION_SETTINGS):
            return record
        # only the decision's settings changed: decided again below from the finished fold
    elif ctx.run.records.begin("self_check", key):  # an attempt under other settings: start over
        _clear(out, keep_aside=False)
    record = run_self_check(ctx.train_scene, ctx.config, out, restorer, progress=ctx.progress,
                            scene_from_config=ctx.scene_from_config)
    ctx.run.records.finish("self_check", key, float(sum(record.get("seconds", {}).values())))
    if ctx.progress:
        print(f"[fixer4d] stage-2 self-check: {record['reason']}", flush=True)
    return record


def final_stage(ctx: StageContext, model, decision: str):
    """The run's final model -> RUN/model_final.ply, as the self-check ``decision`` says: refine
    (stage 2), continue (the matched-iterations control) or skip (the stage-1 model)."""
    from fixer4d.model.io import load_ply, save_ply

    if decision == "refine":
        return stage2(ctx, model)
    final = ctx.path / "model_final.ply"
    key = stage_key(stage2_key(ctx.config), decision)
    if ctx.run.records.done("stage2", key) and final.exists():
        return load_ply(final)
    ctx.run.records.begin("stage2", key)
    _drop_checkpoints(ctx.path, 2)
    t0 = time.perf_counter()
    chosen = matched_stage1(ctx, model) if decision == "continue" else model
    if ctx.config.segments.static_from is not None:  # beside the first segment's final static rows
        from fixer4d.pipeline.shared_static import load_shared, swap_shared_static

        chosen = swap_shared_static(chosen, load_shared(ctx.config.segments.static_from, "final"))
    save_ply(chosen, final)
    ctx.run.records.finish("stage2", key, time.perf_counter() - t0)
    return chosen


# Bumped when evaluation adds or changes a metric or how a row is made, so a finished row is
# scored again.
EVAL_METRICS_VERSION = 3


def evaluate_stage(ctx: StageContext, name: str, render_fn: Callable[[Camera, float], np.ndarray], inputs_key: str,
                   seconds: dict[str, float],
                   unobserved: Callable[[int, int], np.ndarray] | None = None) -> dict[str, Any]:
    """Held-out metrics of ``render_fn`` -> RUN/eval/<slug>/metrics.json (keyed by ``inputs_key``,
    the key of the model or restorer it evaluates). unobserved: the held-out pixels no train
    camera explains (``restoration.UnobservedMasks``), scored as ``psnr_unobserved``. A scene
    without held-out cameras scores the fit to its train views, each through the colour response
    its camera trained (``camera_response.train_view_render_fn``; the sparse init's stage 1 trains
    none)."""
    import json

    from fixer4d.eval.evaluate import evaluate
    from fixer4d.pipeline.report import ROW_COLMAP

    response = None if ctx.scene.test_ids or name == ROW_COLMAP else stage1_response(ctx)
    if response is not None:
        from fixer4d.model.camera_response import train_view_render_fn

        render_fn = train_view_render_fn(render_fn, response, [ctx.scene.cameras[i] for i in ctx.scene.train_ids])
    slug = eval_slug(name)
    out = ctx.path / "eval" / slug
    stage = f"eval:{slug}"
    ev = ctx.config.eval
    key = stage_key("eval", inputs_key, ev.stride, ev.examples, EVAL_METRICS_VERSION, unobserved is not None,
                    *(("train views through their response",) if response is not None else ()))
    if ctx.run.records.done(stage, key) and (out / "metrics.json").exists():
        return json.loads((out / "metrics.json").read_text())
    ctx.run.records.begin(stage, key)
    t0 = time.perf_counter()
    metrics = evaluate(render_fn, ctx.scene, out, frame_stride=ev.stride, method_name=name, seconds=seconds,
                       save_examples=ev.examples, progress=ctx.progress, unobserved_fn=unobserved)
    ctx.run.records.finish(stage, key, time.perf_counter() - t0)
    return metrics


def eval_slug(name: str) -> str:
    """A report row's folder name: "STGS w/ MVS" -> "stgs-w-mvs"."""
    import re

    return re.sub(r"[^a-z0-9._-]+", "-", name.lower().replace("/", "")).strip("-") or "model"


def retire_stage2(ctx: StageContext) -> None:
    """The config runs no stage 2 (R = 0) but an earlier one ran here: its model moves to
    RUN/stale/ (never left to pass for this config's "Full" model), its record and checkpoints go."""
    final = ctx.path / "model_final.ply"
    forgot = ctx.run.records.forget("stage2")
    _drop_checkpoints(ctx.path, 2)
    if final.exists():
        log.warning("stage 2 is off (rounds = 0): moved the earlier %s to %s", final, _move_aside(final))
    elif forgot:
        log.warning("stage 2 is off (rounds = 0): dropped the earlier stage-2 record")


def _finished(ctx: StageContext, run_dir: Path, stage: int) -> None:
    """A stage's outputs are written: its checkpoints under ``run_dir`` go, unless the run keeps them."""
    if not ctx.keep_checkpoints:
        _drop_checkpoints(run_dir, stage)


def _drop_checkpoints(run_dir: Path, stage: int) -> None:
    """Delete the trainer checkpoints of ``stage`` under ``run_dir`` (a finished or stale stage)."""
    from fixer4d.train.trainer import Trainer

    for ckpt in Trainer.list_checkpoints(run_dir, stage):
        ckpt.unlink(missing_ok=True)


def _clear(path: Path, keep_aside: bool = True) -> None:
    """Remove a stage's partial output; with ``keep_aside`` it goes to RUN/stale/<name>-<n> instead
    (a cache of restored clips costs minutes to recompute; the user may want to look at it)."""
    if not path.exists():
        return
    if not keep_aside or not path.is_dir() or not any(path.iterdir()):
        shutil.rmtree(path) if path.is_dir() else path.unlink()
        return
    log.warning("moved %s (made with other settings) to %s", path, _move_aside(path))


def _move_aside(path: Path) -> Path:
    """Move ``path`` to RUN/stale/<name>-<n> (the first free n); returns where it went."""
    stale = path.parent / "stale"
    stale.mkdir(exist_ok=True)
    n = 0
    while (stale / f"{path.name}-{n}").exists():
        n += 1
    path.rename(stale / f"{path.name}-{n}")
    return stale / f"{path.name}-{n}"
