"""`fixer4d refine RUN`: stage 2 (restoration-guided refinement) of a run, with the run's own config.

Opens RUN (made by `fixer4d run` or `fixer4d reconstruct`), applies the stage-2 options given here
to its config (stage2.*, restorer.*, trajectories.*, eval.*, self_check.*; everything else is the run's), and
runs the pipeline's stages: finished ones are reused, stage 2 runs (or resumes), and the rows that
depend on it are evaluated. Changing a stage-2 setting recomputes stage 2 and its pseudo-targets
(the old cache is moved to RUN/stale/).
"""
from __future__ import annotations

import argparse

from fixer4d.errors import InputError
from fixer4d.cli.config_args import (add_keep_checkpoints_argument, add_paper_stage2_argument, maybe_print_config,
                                     paper_stage2_overrides)

# Sections refine may change: anything else would make the stage-1 model stale.
REFINABLE = ("stage2.", "restorer.", "trajectories.", "eval.", "self_check.")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("run", help="a run folder made by `fixer4d run` or `fixer4d reconstruct`")
    parser.add_argument("--rounds", type=int, default=None, help="cache refresh rounds R (default: the run's, or 2)")
    parser.add_argument("--refresh-every", type=int, default=None, help="iterations K between cache refreshes")
    parser.add_argument("--lambda-gen", type=float, default=None, help="weight of the pseudo-view L1 (0.5)")
    parser.add_argument("--iterations", type=int, default=None, help="stage-2 iterations (default R x K)")
    parser.add_argument("--batch-pseudo", type=int, default=None, help="cached frames per iteration")
    parser.add_argument("--no-confidence", action="store_true", help="plain L1 instead of confidence-weighted")
    parser.add_argument("--eval-stride", type=int, default=None, help="evaluate every S-th frame")
    add_paper_stage2_argument(parser)
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help=f"a config value in {', '.join(k.rstrip('.') for k in REFINABLE)} by dotted key")
    parser.add_argument("--print-config", action="store_true", help="print the resolved config and exit")
    parser.add_argument("--no-progress", "--quiet", dest="quiet", action="store_true", help="no progress bars")
    add_keep_checkpoints_argument(parser)


def run(args: argparse.Namespace) -> int:
    from fixer4d.pipeline import config_tree
    from fixer4d.pipeline.config import resolve
    from fixer4d.pipeline.run import run_stages
    from fixer4d.pipeline.run_folder import RunFolder
    from fixer4d.pipeline.stages import StageContext
    from fixer4d.train.config import Stage2Config

    folder = RunFolder.open(args.run)
    if not (folder.path / "model_stage1.ply").is_file():
        from fixer4d.cli.export import missing_model_message

        raise InputError(missing_model_message(folder.path, ("model_stage1.ply",)))
    overrides = {k: v for k, v in {
        "stage2.rounds": args.rounds, "stage2.refresh_every": args.refresh_every, "stage2.lambda_gen": args.lambda_gen,
        "stage2.iterations": args.iterations, "stage2.batch_pseudo": args.batch_pseudo,
        "stage2.confidence_weighting": False if args.no_confidence else None, "eval.stride": args.eval_stride,
    }.items() if v is not None}
    if args.iterations is not None and args.iterations < 1:
        raise InputError(f"refine --iterations {args.iterations}: must be >= 1 (leave it out for R x K)")
    overrides.update(paper_stage2_overrides(args))
    overrides.update(config_tree.parse_set_overrides(args.set))
    bad = [k for k in overrides if not k.startswith(REFINABLE)]
    if bad:
        raise InputError(f"refine: {', '.join(bad)} would change the stage-1 model; refine may set "
                         f"{', '.join(k + '*' for k in REFINABLE)} (start a new run for the rest)")
    current = folder.config.to_dict()
    if current["stage2"]["rounds"] == 0 and "stage2.rounds" not in overrides:
        overrides["stage2.rounds"] = Stage2Config().rounds  # a reconstruction: refine means stage 2
    if ({"stage2.rounds", "stage2.refresh_every"} & set(overrides) and "stage2.iterations" not in overrides
            and current["stage2"].get("iterations") is not None):
        overrides["stage2.iterations"] = None  # R x K of the new rounds, not a count an earlier refine set
    config = resolve(config_file=current, overrides=overrides, defaults={})
    if maybe_print_config(args, config):
        return 0
    folder.update_config(config)
    report = run_stages(StageContext(run=folder, scene=folder.scene, progress=not args.quiet,
                                     keep_checkpoints=args.keep_checkpoints, scene_from_config=True))
    for row in report["rows"]:
        if row.get("status") == "ok":
            print(f"{row['method']}: held-out PSNR {row['psnr']:.2f} dB")
    model = "model_final.ply" if config.stage2.rounds > 0 else "model_stage1.ply (rounds = 0: no stage 2)"
    print(f"-> {folder.path}/{model}, {folder.path}/report.md")
    return 0
