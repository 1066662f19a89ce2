"""`fixer4d refine RUN`: stage 2, restoration-guided refinement of a reconstructed run.

Starts from RUN/model_stage1.ply, trains with L = L_STG + lambda_gen * L1(pseudo-view, cached
restored frame) on the restoration cache under RUN/cache, refreshing it every K iterations through
``fixer4d.pipeline.make_refresh_callback(run_dir, scene, PipelineConfig)`` (the pipeline renders the
trajectories with the current model and restores them). Writes RUN/model_final.ply and evaluates
it into RUN/eval/full and RUN/metrics.json. A rerun resumes from RUN/checkpoints.
"""
from __future__ import annotations

import argparse
import json
import logging
from pathlib import Path

from fixer4d.errors import InputError

log = logging.getLogger("fixer4d.train")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run", help="a run folder made by `fixer4d reconstruct` or `fixer4d run`")
    parser.add_argument("--rounds", type=int, default=None, help="cache refresh rounds R")
    parser.add_argument("--refresh-every", type=int, default=None, help="iterations K between cache refreshes")
    parser.add_argument("--lambda-gen", type=float, default=None, help="weight of the pseudo-view L1 (0.5)")
    parser.add_argument("--iterations", type=int, default=None, help="stage-2 iterations (default R x K)")
    parser.add_argument("--batch-pseudo", type=int, default=None, help="cached frames per iteration")
    parser.add_argument("--no-confidence", action="store_true", help="plain L1 instead of confidence-weighted")
    parser.add_argument("--backend", default=None, help="renderer override: auto, cpu, reference or gsplat")
    parser.add_argument("--eval-stride", type=int, default=1, help="evaluate every S-th frame")
    parser.add_argument("--no-progress", action="store_true", help="no progress bars")


def stage2_config(args: argparse.Namespace, stored: dict | None):
    """Stage2Config from RUN/config.json's "stage2" (if any) overridden by the command line."""
    from fixer4d.train.config import Stage2Config

    d = dict(stored or {})
    for key, value in (("rounds", args.rounds), ("refresh_every", args.refresh_every),
                       ("lambda_gen", args.lambda_gen), ("iterations", args.iterations),
                       ("batch_pseudo", args.batch_pseudo)):
        if value is not None:
            d[key] = value
    if args.no_confidence:
        d["confidence_weighting"] = False
    return Stage2Config.from_dict(d)


def load_refresh_callback(run_dir: Path, scene, config: dict, *, progress: bool = True, backend: str = "auto"):
    """The pipeline's cache-refresh callback for this run's config.json, or None when the
    pipeline is not available (then the existing cache is used as is)."""
    import dataclasses

    try:
        from fixer4d.pipeline import PipelineConfig, make_refresh_callback
    except ImportError as exc:
        log.warning("fixer4d.pipeline.make_refresh_callback unavailable (%s): refining on the existing cache "
                    "without refreshing it", exc)
        return None
    known = {f.name for f in dataclasses.fields(PipelineConfig)}
    pipeline_config = PipelineConfig.from_dict({k: v for k, v in config.items() if k in known})
    return make_refresh_callback(run_dir, scene, pipeline_config, progress=progress, backend=backend)


def run(args: argparse.Namespace) -> int:
    import time

    from fixer4d.atomic import write_json
    from fixer4d.eval.evaluate import evaluate
    from fixer4d.model.io import load_ply, save_ply
    from fixer4d.restore.cache import RestoreCache
    from fixer4d.scene import load_scene
    from fixer4d.train.cli import update_run_config
    from fixer4d.train.config import Stage1Config
    from fixer4d.train.trainer import Trainer

    run_dir = Path(args.run)
    cfg_path = run_dir / "config.json"
    model_path = run_dir / "model_stage1.ply"
    if not cfg_path.is_file() or not model_path.is_file():
        raise InputError(f"{run_dir}: needs config.json and model_stage1.ply; run `fixer4d reconstruct SCENE "
                         f"--out {run_dir}` first")
    config = json.loads(cfg_path.read_text())
    progress = not args.no_progress
    s1 = Stage1Config.from_dict(dict(config.get("stage1", {}), progress=progress,
                                     **({"backend": args.backend} if args.backend else {})))
    s2 = stage2_config(args, config.get("stage2"))
    config = update_run_config(run_dir, {"stage2": s2.to_dict()})
    scene_cfg = dict(config["scene"])
    if scene_cfg.get("frame_range") is not None:
        scene_cfg["frame_range"] = tuple(scene_cfg["frame_range"])
    scene = load_scene(**scene_cfg)

    cache = RestoreCache(run_dir / "cache")
    refresh = load_refresh_callback(run_dir, scene, config, progress=progress, backend=s1.backend)
    if refresh is None and cache.latest_round() is None:
        raise InputError(f"{run_dir / 'cache'}: no restored clips and no pipeline to make them; run "
                         f"`fixer4d run` on this scene first")
    trainer = Trainer(load_ply(model_path), scene, s1, run_dir=run_dir, stage2=s2, cache=cache,
                      refresh_cache=refresh)
    if trainer.resume():
        print(f"resumed stage 2 at step {trainer.step_count}/{trainer.total_iterations}")
    trainer.train()
    save_ply(trainer.model, run_dir / "model_final.ply")

    tic = time.perf_counter()
    prior = {}
    stage1_metrics = run_dir / "eval" / "stage1" / "metrics.json"
    if stage1_metrics.is_file():
        prior = json.loads(stage1_metrics.read_text()).get("seconds", {}) or {}
    seconds = {"prep": prior.get("prep"), "train": (prior.get("train") or 0.0) + trainer.train_seconds}
    metrics = evaluate(trainer.render_fn(), scene, run_dir / "eval" / "full", frame_stride=args.eval_stride,
                       method_name="Full", seconds=seconds, progress=progress)
    metrics.setdefault("seconds", {})["eval"] = metrics["seconds"].get("eval", time.perf_counter() - tic)
    write_json(run_dir / "metrics.json", metrics)
    m = metrics["mean"]
    print(f"stage 2 held-out: PSNR {m['psnr']:.2f} dB, DSSIM1 {m['dssim1']:.4f}, DSSIM2 {m['dssim2']:.4f} "
          f"-> {run_dir / 'metrics.json'}")
    return 0
