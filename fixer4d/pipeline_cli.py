"""`fixer4d run SCENE --out RUN`: the whole method (fixer4d/pipeline.py), resumable."""
from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("scene", help="'demo', a spec .json, or a directory (Neural3DV / Panoptic layout)")
    parser.add_argument("--out", required=True, help="run folder (created; an existing one with the same config resumes)")
    parser.add_argument("--scale", type=float, default=None, help="image scale, e.g. 0.5 for half resolution")
    parser.add_argument("--frames", default=None, help="frame range a:b (half-open)")
    parser.add_argument("--iterations", type=int, default=None, help="stage 1 iterations")
    parser.add_argument("--rounds", type=int, default=None, help="stage 2 rounds R (0 = no restoration)")
    parser.add_argument("--refresh-every", type=int, default=None, help="stage 2 cache refresh interval K (iterations)")
    parser.add_argument("--lambda-gen", type=float, default=None, help="weight of the pseudo-supervision (default 0.5)")
    parser.add_argument("--init", choices=["mvs", "sparse"], default=None, help="initialization of the main model")
    parser.add_argument("--no-baseline", action="store_true", help="skip the STGS w/ COLMAP baseline row")
    parser.add_argument("--restorer", choices=["learned", "warp", "cogvideo"], default=None,
                        help="restorer of stage 2 (learned: trained per scene on its train cameras)")
    parser.add_argument("--eval-stride", type=int, default=None, help="evaluate every S-th frame")
    # [B2 effects] effects decided by evidence (auto), every effect (all) or none (static)
    parser.add_argument("--effects", choices=["auto", "all", "static"], default=None,
                        help="spacetime effects: decided by evidence (auto, default), all, or static only; "
                             "force one with --set effects.motion_degree=N (sh_degree, rotation_velocity, temporal_opacity)")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="any config override by dotted key, e.g. --set trajectories.frames=6 (JSON values)")
    parser.add_argument("--quiet", action="store_true", help="no progress bars")


def run(args: argparse.Namespace) -> int:
    from fixer4d.errors import InputError
    from fixer4d.pipeline import apply_overrides, default_config, parse_set_overrides, run_pipeline

    overrides: dict = {}
    if args.scale is not None:
        overrides["scene.scale"] = args.scale
    if args.frames:
        a, sep, b = args.frames.partition(":")
        if not sep or not a.isdigit() or not b.isdigit() or int(b) <= int(a):
            raise InputError(f"--frames {args.frames!r}: expected a:b with a < b, e.g. 0:20")
        overrides["scene.frame_range"] = [int(a), int(b)]
    for flag, key in (("iterations", "stage1.iterations"), ("rounds", "stage2.rounds"),
                      ("refresh_every", "stage2.refresh_every"), ("lambda_gen", "stage2.lambda_gen"),
                      ("init", "init.method"), ("eval_stride", "eval_stride"), ("restorer", "restorer.kind"),
                      ("effects", "effects.mode")):
        if getattr(args, flag) is not None:
            overrides[key] = getattr(args, flag)
    if args.no_baseline:
        overrides["baseline_sparse"] = False
    overrides.update(parse_set_overrides(args.set))
    config = apply_overrides(default_config(args.scene), overrides)
    run_pipeline(config, args.out, progress=not args.quiet)
    print(open(f"{args.out}/report.md").read())
    return 0
