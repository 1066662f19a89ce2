"""The whole method, resumable: init -> stage 1 -> (restore -> refine) x R -> evaluate, one row
per method of the paper's Table 2 (``report.ROW_NAMES``).

``run_pipeline(config, out)`` checks the scene and the folder before writing anything, then runs
the stage functions (``stages``); every finished stage is reused on a rerun and a killed one
resumes. A row whose stage fails (the sparse baseline finding no points) is reported with its
reason while the others run.
"""
from __future__ import annotations

import dataclasses
import json
import logging
from pathlib import Path
from typing import Any

import numpy as np
import torch

from fixer4d import atomic, numerics
from fixer4d.pipeline import report as R
from fixer4d.pipeline import stages as S
from fixer4d.pipeline.config import RunConfig
from fixer4d.pipeline.keys import co_fields_weight_key
from fixer4d.pipeline.restoration import (TwinWeight, UnobservedMasks, blur_render_fn, pseudo_view_summary,
                                          restoration_render_fn, run_restorer, twin_weight_for)
from fixer4d.pipeline.run_folder import RunFolder, load_scene_for, stage_key
from fixer4d.pipeline.shared_static import SHARED_DIR, export_shared_static
from fixer4d.pipeline.stage_cache import StageCache
from fixer4d.render.views import model_render_fn
from fixer4d.threads import digit_threads
from fixer4d.train.device import device_kind, training_device

log = logging.getLogger("fixer4d.pipeline")


def open_context(config: RunConfig, out: str | Path, *, progress: bool = True,
                 stage_cache: str | Path | None = None, keep_checkpoints: bool = False) -> S.StageContext:
    """Load and check the scene, then create (or resume) the run folder: a bad scene or frame
    range fails here, before anything is written."""
    from fixer4d.scene import validate_scene

    scene = load_scene_for(config)
    validate_scene(scene)  # a video that opens but does not decode fails here, naming file and frame
    if config.restorer.kind == "cogvideo":  # an unavailable restorer stops before any work
        run_restorer(config)
    training_device(config.training.device, config.training.backend)  # a device that is not there, likewise
    run = RunFolder.create(out, config)
    return S.StageContext(run=run, scene=scene, progress=progress,
                          cache=StageCache(stage_cache) if stage_cache is not None else None,
                          keep_checkpoints=keep_checkpoints, scene_from_config=True)


@digit_threads()
def run_pipeline(config: RunConfig, out: str | Path, *, progress: bool = True,
                 stage_cache: str | Path | None = None, keep_checkpoints: bool = False) -> dict[str, Any]:
    """Run (or resume) the whole method; returns the report dict (also RUN/report.json).

    stage_cache: a folder shared by several runs (a study) where finished inits and stage-1
    models are kept and reused by runs whose settings match. keep_checkpoints: keep each stage's
    checkpoints after its outputs are written (by default they go).
    """
    if config.segments.frames is not None:
        return run_segmented(config, out, progress=progress, stage_cache=stage_cache, keep_checkpoints=keep_checkpoints)
    ctx = open_context(config, out, progress=progress, stage_cache=stage_cache, keep_checkpoints=keep_checkpoints)
    return run_stages(ctx)


@digit_threads()
def run_stages(ctx: S.StageContext) -> dict[str, Any]:
    """Every stage the config asks for, in order, writing the report after each row."""
    config = ctx.config
    torch.manual_seed(config.seed)
    if ctx.progress:
        print(f"[fixer4d] {ctx.scene.describe()}", flush=True)
        note = numerics.lock_note(numerics.lock_differences())
        if note:
            print(f"[fixer4d] note: {note}", flush=True)
    rec = ctx.run.records
    report = _Report(ctx)
    method = config.init_method
    if config.baseline_sparse and method != "sparse":
        _baseline_sparse_row(ctx, report)

    # -- ours: dense init + stage 1 ------------------------------------------------------------
    clouds = S.init_stage(ctx, method)
    model = S.stage1(ctx, method, clouds, ctx.path / "model_stage1.ply", "stage1")
    main_row = R.ROW_MVS if method != "sparse" else R.ROW_COLMAP
    s1_key = S.stage1_key(config, method)
    # the held-out pixels no train camera explains, from the stage-1 model: one region for every row
    unobserved = UnobservedMasks(model, ctx.scene, config.stage2.visibility, ctx.backend)
    m = S.evaluate_stage(ctx, main_row, model_render_fn(model, ctx.backend, ctx.background), s1_key,
                         report.seconds("stage1"), unobserved)
    report.add(R.metrics_row(main_row, m, rec.seconds(f"init_{method}", "stage1")))
    final_metrics = m

    needs_restorer = config.eval.restoration_rows or config.stage2.rounds > 0
    restorer = S.restorer_stage(ctx, clouds, model) if needs_restorer else None
    del clouds
    # restored renders replace the render only where the train cameras leave a pixel unobserved
    # (eval.gate_restoration; None: the paper's restoration rows, every pixel)
    gate = config.stage2.visibility if config.eval.gate_restoration else None
    restored_init = None
    if restorer is not None and config.eval.restoration_rows:
        restored_init = _stage1_restoration_rows(ctx, report, model, restorer, gate, unobserved, m, s1_key)

    # -- stage 2: (restore -> refine) x R, checked on a held-back train camera, and its matched-
    # iterations control
    if config.stage2.rounds > 0:
        if config.eval.matched_row:
            _matched_row(ctx, report, model, unobserved)
        check = S.self_check_stage(ctx, restorer)
        report.checks["self_check"] = check
        model = S.final_stage(ctx, model, check["decision"])
        if check["decision"] == "refine":
            report.checks["pseudo_views"] = pseudo_view_summary(ctx.path / "cache")
        if check["decision"] == "skip":  # the final model is the stage-1 model: its rows are those rows
            final_metrics = _skipped_final_rows(ctx, report, m, restored_init)
        else:
            final_metrics = _final_rows(ctx, report, model, check["decision"], restorer, gate, unobserved)
    else:
        S.retire_stage2(ctx)
    atomic.write_json(ctx.path / "metrics.json", final_metrics)
    return report.write()


class _Report:
    """The rows computed so far; RUN/report.json is rewritten after each one."""

    def __init__(self, ctx: S.StageContext) -> None:
        self.ctx = ctx
        self.rows: list[dict[str, Any]] = []
        self.checks: dict[str, Any] = {}  # the stage-2 self-check and pseudo-view summaries

    def add(self, row: dict[str, Any]) -> None:
        self.rows.append(row)
        self.write()

    def write(self) -> dict[str, Any]:
        ctx = self.ctx
        return R.write_report(ctx.path, ctx.scene.describe(), _ordered(self.rows), ctx.run.records.as_seconds(),
                              self.extra())

    def extra(self) -> dict[str, Any]:
        out = {"restorer": S.restorer_summary(self.ctx), "peak_rss_mb": peak_rss_mb(),
               "numerics": numerics.status(), **self.checks,
               # where this run's trainings ran: a stage trained on another device has another key
               "training_device": device_kind(self.ctx.config.training.device, self.ctx.config.training.backend)}
        terms = S.terms_path(self.ctx.path)
        if terms.is_file():  # the main model's terms and why
            out["model"] = json.loads(terms.read_text())
        return out

    def seconds(self, *stages: str) -> dict[str, float]:
        """A row's evaluate seconds: the main init as preparation, ``stages`` as training."""
        rec = self.ctx.run.records
        return {"prep": rec.seconds(f"init_{self.ctx.config.init_method}"), "train": rec.seconds(*stages)}


def _baseline_sparse_row(ctx: S.StageContext, report: _Report) -> None:
    """STGS from the sparse (COLMAP) init; its failure becomes its row's reason and never stops
    the main method."""
    config, rec = ctx.config, ctx.run.records
    try:
        clouds = S.init_stage(ctx, "sparse")
        base = S.stage1(ctx, "sparse", clouds, ctx.path / "baseline_sparse" / "model_stage1.ply", "stage1_sparse")
        m = S.evaluate_stage(ctx, R.ROW_COLMAP, model_render_fn(base, ctx.backend, ctx.background),
                             S.stage1_key(config, "sparse"),
                             {"prep": rec.seconds("init_sparse"), "train": rec.seconds("stage1_sparse")})
        report.add(R.metrics_row(R.ROW_COLMAP, m, rec.seconds("init_sparse", "stage1_sparse")))
        del base
    except Exception as exc:  # noqa: BLE001 - any baseline failure becomes its row's reason
        log.warning("baseline %s failed: %s", R.ROW_COLMAP, exc)
        if ctx.progress:
            print(f"[fixer4d] {R.ROW_COLMAP} failed ({exc}); continuing with the main method", flush=True)
        report.add(R.failed_row(R.ROW_COLMAP, str(exc)))


def _stage1_restoration_rows(ctx: S.StageContext, report: _Report, model, restorer, gate, unobserved,
                             stage1_metrics: dict[str, Any], s1_key: str) -> dict[str, Any]:
    """The rows around the restorer on the stage-1 model: identity (the render itself), a blur
    of it, and its restoration; returns the restoration's metrics."""
    config, rec = ctx.config, ctx.run.records
    method = config.init_method
    report.add(R.copied_row(R.ROW_IDENTITY, stage1_metrics))
    blur = blur_render_fn(model, config.eval.blur_sigma_px, ctx.backend, ctx.background)
    mb = S.evaluate_stage(ctx, R.ROW_BLUR, blur, stage_key(s1_key, "blur", config.eval.blur_sigma_px),
                          report.seconds("stage1"), unobserved)
    report.add(R.metrics_row(R.ROW_BLUR, mb, rec.seconds(f"init_{method}", "stage1")))
    m = S.evaluate_stage(ctx, R.ROW_RESTORED_INIT,
                         restoration_render_fn(model, ctx.scene, restorer, ctx.backend, gate,
                                               config.eval.fill_unobserved, _twin(ctx, gate), ctx.background),
                         stage_key(s1_key, S.restorer_key(config), gate_settings(gate, config.eval.fill_unobserved),
                                   *co_fields_weight_key(config)),
                         report.seconds("stage1", "restorer"), unobserved)
    report.add(R.metrics_row(R.ROW_RESTORED_INIT, m, rec.seconds(f"init_{method}", "stage1", "restorer")
                             + rec.seconds(f"eval:{S.eval_slug(R.ROW_RESTORED_INIT)}")))
    return m


def _matched_row(ctx: S.StageContext, report: _Report, model, unobserved) -> None:
    """Stage 1 continued as long as stage 2 trains, without pseudo-views (the control row)."""
    config, rec = ctx.config, ctx.run.records
    matched = S.matched_stage1(ctx, model)
    m = S.evaluate_stage(ctx, R.ROW_MATCHED, model_render_fn(matched, ctx.backend, ctx.background),
                         S.matched_key(config), report.seconds("stage1", "matched"), unobserved)
    report.add(R.metrics_row(R.ROW_MATCHED, m, rec.seconds(f"init_{config.init_method}", "stage1", "matched")))
    del matched


def _final_rows(ctx: S.StageContext, report: _Report, model, decision: str, restorer, gate,
                unobserved) -> dict[str, Any]:
    """The final model's row and its restoration row; returns the final model's metrics."""
    config, rec = ctx.config, ctx.run.records
    # what the final model cost: the continued model is the matched control's training
    trained = ("matched",) if decision == "continue" else ()
    full_secs = rec.seconds(f"init_{config.init_method}", "stage1", "restorer", "self_check", *trained, "stage2")
    s2_key = stage_key(S.stage2_key(config), decision)
    final = S.evaluate_stage(ctx, R.ROW_FULL, model_render_fn(model, ctx.backend, ctx.background), s2_key,
                             report.seconds("stage1", "restorer", "self_check", "stage2"), unobserved)
    report.add(R.metrics_row(R.ROW_FULL, final, full_secs))
    if restorer is not None and config.eval.restoration_rows:
        m = S.evaluate_stage(ctx, R.ROW_RESTORED_REFINED,
                             restoration_render_fn(model, ctx.scene, restorer, ctx.backend, gate,
                                               config.eval.fill_unobserved, _twin(ctx, gate), ctx.background),
                             stage_key(s2_key, S.restorer_key(config),
                                       gate_settings(gate, config.eval.fill_unobserved)),
                             report.seconds("stage1", "restorer", "stage2"), unobserved)
        report.add(R.metrics_row(R.ROW_RESTORED_REFINED, m, full_secs
                                 + rec.seconds(f"eval:{S.eval_slug(R.ROW_RESTORED_REFINED)}")))
    return final


def _skipped_final_rows(ctx: S.StageContext, report: _Report, stage1_metrics: dict[str, Any],
                        restored_init: dict[str, Any] | None) -> dict[str, Any]:
    """The final rows where the self-check kept the stage-1 model: its rows under the final rows'
    names (the same images, not rendered again), with what the final model cost (the check
    included); returns the final model's metrics."""
    rec = ctx.run.records
    full_secs = rec.seconds(f"init_{ctx.config.init_method}", "stage1", "restorer", "self_check", "stage2")
    report.add(R.copied_row(R.ROW_FULL, stage1_metrics, full_secs))
    if restored_init is not None:
        report.add(R.copied_row(R.ROW_RESTORED_REFINED, restored_init, full_secs
                                + rec.seconds(f"eval:{S.eval_slug(R.ROW_RESTORED_INIT)}")))
    return {**stage1_metrics, "method": R.ROW_FULL}


def _twin(ctx: S.StageContext, gate) -> TwinWeight | None:
    """The gated rows' twin-field weight (co_fields.weight; None: the visibility weight alone)."""
    return None if gate is None else twin_weight_for(ctx.config, ctx.path)


def gate_settings(gate, fill: bool) -> dict[str, Any] | None:
    """What a restoration row's images depend on besides the models and the restorer: the gate's
    thresholds and fallback, None for the ungated rows."""
    from fixer4d.restore.unobserved_fill import BACKGROUND_DEPTH_TOL

    return None if gate is None else {**dataclasses.asdict(gate), "fill_unobserved": fill,
                                      **({"fill_background_tol": BACKGROUND_DEPTH_TOL} if fill else {})}


def peak_rss_mb() -> float:
    """Peak resident memory of this process and its finished children, in MiB (Linux ru_maxrss is KiB)."""
    import resource

    return max(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss,
               resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss) / 1024.0


# ---------------------------------------------------------------------------------------------
# long captures: temporal segments on an executor
# ---------------------------------------------------------------------------------------------
# Rows whose model can be stitched over the whole clip, and where each segment run keeps it.
_MODEL_ROWS = ((R.ROW_COLMAP, "baseline_sparse/model_stage1.ply"), (R.ROW_MVS, "model_stage1.ply"),
               (R.ROW_MATCHED, "matched/model.ply"), (R.ROW_FULL, "model_final.ply"))


def segment_config(config: RunConfig, start: int, stop: int, shared: tuple[Path, int] | None = None) -> RunConfig:
    """The config of the segment [start, stop) of ``config``'s clip: the same run on that frame
    range (absolute frames of the source), not segmented again. shared: (folder of the first
    segment's static rows, their SH degree) for a later segment of a run that shares them."""
    import dataclasses

    offset = 0 if config.scene.frame_range is None else config.scene.frame_range[0]
    terms = config.model_terms
    segments = dataclasses.replace(config.segments, frames=None, static_from=None)
    if shared is not None:
        # the shared rows carry the first segment's view dependence: every segment keeps its SH degree
        segments = dataclasses.replace(segments, static_from=str(shared[0]))
        terms = dataclasses.replace(terms, sh_degree=shared[1])
    # the segments already run in parallel on the executor: inside one, restore jobs run locally
    return dataclasses.replace(config, scene=dataclasses.replace(config.scene, frame_range=(offset + start, offset + stop)),
                               segments=segments, model_terms=terms,
                               executor=dataclasses.replace(config.executor, kind="local"))


def _run_segment(job: tuple[dict[str, Any], str, bool]) -> dict[str, Any]:
    """One segment's whole pipeline (a top-level function, so Ray can ship it)."""
    config_dict, out, keep_checkpoints = job
    report = run_pipeline(RunConfig.from_dict(config_dict), out, progress=False, keep_checkpoints=keep_checkpoints)
    report["peak_rss_mb"] = peak_rss_mb()
    return report


def run_segmented(config: RunConfig, out: str | Path, *, progress: bool = True,
                  stage_cache: str | Path | None = None, keep_checkpoints: bool = False) -> dict[str, Any]:
    """Run a long capture as overlapping segments on the configured executor, then evaluate the
    stitched models over the whole clip (``segments.SegmentedModel``)."""
    import time

    from fixer4d.model.io import load_ply
    from fixer4d.pipeline.executors import executor_for
    from fixer4d.pipeline.segments import SegmentedModel, owners, segment_dir, split_segments

    ctx = open_context(config, out, progress=progress, stage_cache=stage_cache, keep_checkpoints=keep_checkpoints)
    scene = ctx.scene
    ranges = split_segments(scene.num_frames, config.segments.frames, config.segments.overlap)
    dirs = [str(segment_dir(ctx.path, k, r)) for k, r in enumerate(ranges)]
    jobs = [(segment_config(config, s, e).to_dict(), d, keep_checkpoints) for (s, e), d in zip(ranges, dirs)]
    sharing = config.segments.share_static and len(ranges) > 1
    if progress:
        how = "; the first one first, its static Gaussians shared with the others" if sharing else ""
        print(f"[fixer4d] {len(ranges)} segments {ranges} on the {config.executor.kind} executor{how}", flush=True)
    rec = ctx.run.records
    key = stage_key("segments", [j[0] for j in jobs])
    t0 = time.perf_counter()
    shared_summary = None
    if not rec.done("segments", key):
        rec.begin("segments", key)
        executor = executor_for(config.executor)
        if sharing:
            seg_reports = executor.map(_run_segment, jobs[:1])
            shared_summary = _share_static(config, ctx.path, ranges, dirs, jobs)
            seg_reports += executor.map(_run_segment, jobs[1:])
        else:
            seg_reports = executor.map(_run_segment, jobs)
        rec.finish("segments", key, time.perf_counter() - t0)
    else:
        import json

        seg_reports = [json.loads((Path(d) / "report.json").read_text()) for d in dirs]
        summary_file = ctx.path / "segments" / SHARED_DIR / "summary.json"
        # a folder that once ran with sharing keeps the files; only a sharing run reports them
        shared_summary = json.loads(summary_file.read_text()) if sharing and summary_file.is_file() else None

    own = owners(scene.num_frames, ranges)
    share = np.bincount(own, minlength=len(ranges)) / float(scene.num_frames)
    rows: list[dict[str, Any]] = []
    for name in R.ROW_NAMES:
        per_seg = [next((r for r in rep["rows"] if r["method"] == name), None) for rep in seg_reports]
        if any(r is None for r in per_seg):
            continue
        failed = [r for r in per_seg if r.get("status") == "failed"]
        if failed:
            rows.append(R.failed_row(name, f"{len(failed)} segment(s) failed: {failed[0].get('error')}"))
            continue
        seconds = float(sum(r["seconds"] or 0.0 for r in per_seg))
        model_file = dict(_MODEL_ROWS).get(name)
        if model_file is None:  # restoration rows: the owned-frame-weighted mean of the segments' rows
            row = {"method": name, "status": "ok", "seconds": seconds, "aggregate": "segment mean"}
            for m in R.METRIC_KEYS:
                vals = [r.get(m) for r in per_seg]
                row[m] = None if any(v is None for v in vals) else float(np.dot(share, vals))
            rows.append(row)
            continue
        stitched = SegmentedModel([load_ply(Path(j[1]) / model_file) for j in jobs], ranges, scene.num_frames)
        m = S.evaluate_stage(ctx, name, model_render_fn(stitched, ctx.backend, ctx.background),
                             stage_key(key, name), {"train": seconds})
        rows.append(R.metrics_row(name, m, seconds))
        del stitched
    extra = {"segments": [{"frames": list(r), "peak_rss_mb": rep.get("peak_rss_mb"),
                           "gaussians": (rep.get("model") or {}).get("gaussians"),
                           "frozen": (rep.get("model") or {}).get("frozen", 0)} for r, rep in zip(ranges, seg_reports)],
             "shared_static": shared_summary,
             "executor": config.executor.kind, "segments_wall_seconds": rec.seconds("segments"),
             "peak_rss_mb": max([peak_rss_mb()] + [rep.get("peak_rss_mb") or 0.0 for rep in seg_reports])}
    stage_seconds = {f"seg{k:02d}:{n}": v for k, rep in enumerate(seg_reports) for n, v in rep["stage_seconds"].items()}
    stage_seconds.update(rec.as_seconds())
    return R.write_report(ctx.path, scene.describe(), rows, stage_seconds, extra)


def _share_static(config: RunConfig, run_dir: Path, ranges, dirs: list[str], jobs: list) -> dict[str, Any] | None:
    """After the first segment: export its static rows and point the later jobs (in place) at
    them. Returns the summary for the report (None: nothing static to share)."""
    shared_dir = Path(run_dir) / "segments" / SHARED_DIR
    summary = export_shared_static(Path(dirs[0]), shared_dir)
    if summary is None:
        log.warning("the first segment has no static Gaussians (model terms %s): nothing to share", config.model_terms.mode)
        return None
    atomic.write_json(shared_dir / "summary.json", summary)
    for k in range(1, len(jobs)):
        s, e = ranges[k]
        jobs[k] = (segment_config(config, s, e, (shared_dir, summary["sh_degree"])).to_dict(), dirs[k], jobs[k][2])
    return summary


def _ordered(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Rows in the paper's order (they are computed in stage order)."""
    order = {name: i for i, name in enumerate(R.ROW_NAMES)}
    return sorted(rows, key=lambda r: order.get(r["method"], len(order)))
