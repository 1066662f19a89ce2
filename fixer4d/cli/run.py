"""`fixer4d run SCENE --out RUN`: the whole method, resumable (fixer4d.pipeline.run)."""
from __future__ import annotations

import argparse
from pathlib import Path

from fixer4d.cli.config_args import (FormerFlag, add_config_arguments, add_keep_checkpoints_argument,
                                     add_paper_stage2_argument, frame_range_override, maybe_print_config,
                                     paper_stage2_overrides, resolve_from_args)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("scene", help="'demo', a spec .json, or a directory (Neural3DV / Panoptic layout, or a capture: "
                                      "one video or image folder per camera)")
    parser.add_argument("--out", help="run folder (created; an existing one with the same config resumes)")
    parser.add_argument("--scale", type=float, default=None, help="image scale, e.g. 0.5 for half resolution")
    parser.add_argument("--frames", default=None, help="frame range a:b of the scene (half-open)")
    parser.add_argument("--iterations", type=int, default=None, help="stage 1 iterations")
    parser.add_argument("--rounds", type=int, default=None, help="stage 2 rounds R (0 = no restoration)")
    parser.add_argument("--refresh-every", type=int, default=None, help="stage 2 cache refresh interval K (iterations)")
    parser.add_argument("--lambda-gen", type=float, default=None, help="weight of the pseudo-supervision (default 0.5)")
    parser.add_argument("--init", choices=["mvs", "sparse"], default=None, help="initialization of the main model")
    parser.add_argument("--restorer", choices=["learned", "warp", "cogvideo"], default=None,
                        help="stage-2 restorer (learned: trained per scene on its own train cameras)")
    parser.add_argument("--model-terms", choices=["auto", "all", "static"], default=None,
                        help="the model's optional terms (motion, view dependence, rotation velocity, temporal "
                             "opacity, camera response): decided by evidence (auto, default), all, or static only; "
                             "force one with --set model_terms.motion_degree=N (sh_degree, rotation_velocity, "
                             "temporal_opacity, camera_response)")
    parser.add_argument("--effects", action=FormerFlag, current="--model-terms", dest="model_terms",
                        choices=["auto", "all", "static"])
    parser.add_argument("--no-baseline", action="store_true", help="skip the STGS w/ COLMAP baseline row")
    add_paper_stage2_argument(parser)
    parser.add_argument("--eval-stride", type=int, default=None, help="evaluate every S-th frame")
    parser.add_argument("--segment-frames", type=int, default=None,
                        help="train a long capture as overlapping temporal segments of F frames")
    parser.add_argument("--executor", choices=["local", "ray"], default=None,
                        help="where segments and restore jobs run: this process (local, default) or Ray")
    parser.add_argument("--ray-address", default=None,
                        help="join an existing Ray cluster (e.g. auto or ray://HEAD:10001); default: a local Ray")
    parser.add_argument("--calibration", default=None, metavar="FILE",
                        help="capture: rig.json, COLMAP sparse model, transforms.json or poses_bounds.npy (default: one "
                             "beside the videos, else the rig is calibrated from the frames into RUN/rig.json)")
    parser.add_argument("--offset", action="append", default=None, metavar="CAM=N",
                        help="capture: camera CAM's frame N is the capture's frame 0 (repeatable)")
    parser.add_argument("--holdout", action="append", default=None, metavar="CAM",
                        help="capture: evaluate camera CAM held out (repeatable; default: every camera trains)")
    add_config_arguments(parser)
    parser.add_argument("--seed", type=int, default=None,
                        help="seed of the whole run: the run's torch seed and stage 1's and stage 2's "
                             "(`--set seed=S` alone seeds torch only; the stages keep their own seeds)")
    parser.add_argument("--quiet", action="store_true", help="no progress bars")
    add_keep_checkpoints_argument(parser)


def run(args: argparse.Namespace) -> int:
    from fixer4d.errors import InputError
    from fixer4d.pipeline.capture_rig import calibrate_into_run
    from fixer4d.pipeline.run import run_pipeline
    from fixer4d.scene.capture import parse_offsets

    flags = {"scene.scale": args.scale, "scene.frame_range": frame_range_override(args.frames),
             "training.iterations": args.iterations, "stage2.rounds": args.rounds,
             "stage2.refresh_every": args.refresh_every, "stage2.lambda_gen": args.lambda_gen,
             "init.method": args.init, "eval.stride": args.eval_stride, "restorer.kind": args.restorer,
             "model_terms.mode": args.model_terms,
             "baseline_sparse": False if args.no_baseline else None,
             "segments.frames": args.segment_frames, "executor.kind": args.executor,
             "executor.ray_address": args.ray_address,
             "seed": args.seed, "training.seed": args.seed, "stage2.seed": args.seed,
             "scene.offsets": parse_offsets(args.offset) if args.offset else None, "scene.holdout": args.holdout,
             "scene.calibration": str(Path(args.calibration).resolve()) if args.calibration else None}
    flags.update(paper_stage2_overrides(args))
    config = resolve_from_args(args, flags, source=args.scene)
    if maybe_print_config(args, config):
        return 0
    if not args.out:
        raise InputError("--out RUN is required (the run folder)")
    config = calibrate_into_run(config, args.out, progress=not args.quiet)
    run_pipeline(config, args.out, progress=not args.quiet, keep_checkpoints=args.keep_checkpoints)
    print(open(f"{args.out}/report.md").read())
    return 0
