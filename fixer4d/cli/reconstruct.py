"""`fixer4d reconstruct SCENE --init sparse|mvs --out RUN`: init + stage 1 + held-out evaluation.

The pipeline's own stages with stage 2, the baseline row and the restoration rows switched off;
`fixer4d refine RUN` continues the same run folder with stage 2.
"""
from __future__ import annotations

import argparse

from fixer4d.cli.config_args import (add_config_arguments, add_keep_checkpoints_argument, frame_range_override,
                                     maybe_print_config, resolve_from_args)

# What makes a run a reconstruction: no stage 2 and no extra rows.
RECONSTRUCT_ONLY = {"stage2.rounds": 0, "baseline_sparse": False, "eval.restoration_rows": False,
                    "eval.matched_row": False}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("scene", help='"demo", a scene spec .json, or a Neural3DV/Panoptic folder')
    parser.add_argument("--init", choices=["mvs", "sparse"], default=None,
                        help="point-cloud initialization: sparse (COLMAP baseline) or mvs (dense, ours; default)")
    parser.add_argument("--out", help="run folder (created; a rerun with the same settings resumes)")
    parser.add_argument("--iterations", type=int, default=None,
                        help="training iterations (the densification schedule scales with it)")
    parser.add_argument("--scale", "--resolution", dest="scale", type=float, default=None,
                        help="image scale, e.g. 0.5 for half resolution")
    parser.add_argument("--frames", default=None, help="frame range a:b of the scene (half-open), default all")
    parser.add_argument("--seed", type=int, default=None)
    parser.add_argument("--backend", default=None, help="renderer: auto, cpu, reference or gsplat")
    parser.add_argument("--eval-stride", type=int, default=None, help="evaluate every S-th frame")
    add_config_arguments(parser)
    parser.add_argument("--no-progress", "--quiet", dest="quiet", action="store_true", help="no progress bars")
    add_keep_checkpoints_argument(parser)


def run(args: argparse.Namespace) -> int:
    from fixer4d.errors import InputError
    from fixer4d.pipeline.run import run_pipeline

    flags = {"init.method": args.init, "training.iterations": args.iterations, "scene.scale": args.scale,
             "scene.frame_range": frame_range_override(args.frames), "seed": args.seed,
             "training.seed": args.seed, "training.backend": args.backend, "eval.stride": args.eval_stride}
    config = resolve_from_args(args, flags, source=args.scene, forced=RECONSTRUCT_ONLY)
    if maybe_print_config(args, config):
        return 0
    if not args.out:
        raise InputError("--out RUN is required (the run folder)")
    report = run_pipeline(config, args.out, progress=not args.quiet, keep_checkpoints=args.keep_checkpoints)
    row = report["rows"][-1]
    print(f"{row['method']}: held-out PSNR {row['psnr']:.2f} dB, DSSIM1 {row['dssim1']:.4f} "
          f"-> {args.out}/model_stage1.ply, {args.out}/metrics.json")
    return 0
