"""`fixer4d reconstruct SCENE --init sparse|mvs --out RUN`: stage 1 end to end.

Loads the scene, writes RUN/config.json, initializes per-frame clouds into RUN/init (reused when
init_report.json exists), trains spacetime Gaussians on the observed views (resuming from
RUN/checkpoints), writes RUN/model_stage1.ply and evaluates the held-out cameras into
RUN/eval/stage1 and RUN/metrics.json.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from fixer4d.errors import InputError

# Table-2 row names of the two inits (the report's method names).
METHOD_NAMES = {"sparse": "STGS w/ COLMAP", "mvs": "STGS w/ MVS"}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("scene", help='"demo", a scene spec .json, or a Neural3DV/Panoptic folder')
    parser.add_argument("--init", choices=sorted(METHOD_NAMES), default="mvs",
                        help="point-cloud initialization: sparse (COLMAP baseline) or mvs (dense, ours)")
    parser.add_argument("--out", required=True, help="run folder (created; a rerun resumes)")
    parser.add_argument("--iterations", type=int, default=None,
                        help="training iterations (the densification schedule scales with it)")
    parser.add_argument("--resolution", type=float, default=1.0, help="image scale, e.g. 0.5 for half resolution")
    parser.add_argument("--frames", default=None, help="frame range a:b (half-open), default all")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--backend", default="auto", help="renderer: auto, cpu, reference or gsplat")
    parser.add_argument("--eval-stride", type=int, default=1, help="evaluate every S-th frame")
    parser.add_argument("--no-progress", action="store_true", help="no progress bars")


def parse_frames(text: str | None) -> tuple[int, int] | None:
    """'a:b' -> (a, b); None -> None."""
    if text is None:
        return None
    try:
        a, b = (int(x) for x in text.split(":"))
    except ValueError:
        raise InputError(f"--frames {text!r}: expected a:b, e.g. 0:30") from None
    if not 0 <= a < b:
        raise InputError(f"--frames {text!r}: need 0 <= a < b")
    return a, b


def update_run_config(run_dir: Path, updates: dict[str, Any]) -> dict[str, Any]:
    """Merge ``updates`` into RUN/config.json (other stages' keys are kept); written atomically."""
    from fixer4d.atomic import write_json

    path = run_dir / "config.json"
    config: dict[str, Any] = {}
    if path.is_file():
        try:
            config = json.loads(path.read_text())
        except json.JSONDecodeError as exc:
            raise InputError(f"{path}: not valid JSON ({exc}); fix or delete it") from exc
    config.update(updates)
    write_json(path, config)
    return config


def run(args: argparse.Namespace) -> int:
    import time

    from fixer4d.atomic import write_json
    from fixer4d.eval.evaluate import evaluate
    from fixer4d.init import load_frame_clouds, run_init
    from fixer4d.model.io import save_ply
    from fixer4d.scene import load_scene
    from fixer4d.train.config import Stage1Config
    from fixer4d.train.trainer import Trainer, model_from_clouds

    run_dir = Path(args.out)
    frame_range = parse_frames(args.frames)
    progress = not args.no_progress
    scene = load_scene(args.scene, scale=args.resolution, frame_range=frame_range)
    extra = dict(seed=args.seed, backend=args.backend, progress=progress)
    cfg = (Stage1Config.for_iterations(args.iterations, **extra) if args.iterations is not None
           else Stage1Config(**extra))
    scene_dict = {"source": str(args.scene), "scale": float(args.resolution),
                  "frame_range": list(frame_range) if frame_range else None}
    update_run_config(run_dir, {"scene": scene_dict, "init": {"method": args.init}, "stage1": cfg.to_dict()})
    print(scene.describe())

    init_dir = run_dir / "init"
    if (init_dir / "init_report.json").is_file():
        clouds = load_frame_clouds(init_dir)
        report = json.loads((init_dir / "init_report.json").read_text())
        print(f"reusing {init_dir} ({len(clouds)} frame clouds)")
    else:
        clouds, report = run_init(scene, args.init, init_dir, progress=progress)
    prep_s = _report_seconds(report)

    trainer = Trainer(model_from_clouds(clouds, scene, cfg), scene, cfg, run_dir=run_dir)
    if trainer.resume():
        print(f"resumed stage 1 at step {trainer.step_count}/{trainer.total_iterations}")
    trainer.train()
    save_ply(trainer.model, run_dir / "model_stage1.ply")
    print(f"stage 1: {trainer.model.num_gaussians} Gaussians -> {run_dir / 'model_stage1.ply'}")

    tic = time.perf_counter()
    metrics = evaluate(trainer.render_fn(), scene, run_dir / "eval" / "stage1", frame_stride=args.eval_stride,
                       method_name=METHOD_NAMES[args.init],
                       seconds={"prep": prep_s, "train": trainer.train_seconds}, progress=progress)
    metrics.setdefault("seconds", {})["eval"] = metrics["seconds"].get("eval", time.perf_counter() - tic)
    write_json(run_dir / "metrics.json", metrics)
    m = metrics["mean"]
    lp = "n/a" if m.get("lpips") is None else f"{m['lpips']:.4f}"
    print(f"held-out: PSNR {m['psnr']:.2f} dB, DSSIM1 {m['dssim1']:.4f}, DSSIM2 {m['dssim2']:.4f}, LPIPS {lp} "
          f"-> {run_dir / 'metrics.json'}")
    return 0


def _report_seconds(report: dict[str, Any]) -> float | None:
    """Total preparation seconds from an init_report.json (None when it does not say)."""
    sec = report.get("seconds")
    if isinstance(sec, (int, float)):
        return float(sec)
    if isinstance(sec, dict):
        for key in ("preparation", "total"):
            if isinstance(sec.get(key), (int, float)):
                return float(sec[key])
        vals = [v for v in sec.values() if isinstance(v, (int, float))]
        return float(sum(vals)) if vals else None
    return None
