"""`fixer4d study SCENE --out DIR [--budget-minutes M]`: the accuracy-vs-time study (fixer4d/study.py)."""
from __future__ import annotations

import argparse
import json


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("scene", help="scene: 'demo', a spec .json, or a directory (Neural3DV / Panoptic layout)")
    parser.add_argument("--out", required=True, help="study folder (runs/, study.json, study.md, plots)")
    parser.add_argument("--budget-minutes", type=float, default=None, help="stop starting new variants after this long")
    parser.add_argument("--variants", default=None,
                        help="JSON file with a list of variants ({'name': ..., 'dotted.key': value}); default: the built-in sweep")
    parser.add_argument("--only", default=None, help="comma-separated variant names to run from the sweep")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="override applied to every variant, e.g. --set training.iterations=800 (JSON values)")
    parser.add_argument("--rank", default="psnr", choices=["psnr", "psnr_dynamic", "psnr_static"],
                        help="what 'the fastest variant within 0.5 dB of the best' ranks by: all pixels (default), "
                             "the held-out moving-content mask's, or the static pixels' PSNR")
    parser.add_argument("--quiet", action="store_true")


def run(args: argparse.Namespace) -> int:
    from fixer4d.errors import InputError
    from fixer4d.pipeline.config_tree import parse_set_overrides
    from fixer4d.study import DEFAULT_SWEEP, StudyConfig, check_variants, fastest_within, run_study

    variants = DEFAULT_SWEEP
    if args.variants:
        try:
            with open(args.variants) as fh:
                variants = json.load(fh)
        except (OSError, json.JSONDecodeError) as exc:
            raise InputError(f"--variants {args.variants}: cannot read a JSON list of variants ({exc})") from exc
        try:
            check_variants(variants)
        except InputError as exc:
            raise InputError(f"--variants {args.variants}: {exc}") from None
    if args.only:
        wanted = [s.strip() for s in args.only.split(",") if s.strip()]
        unknown = set(wanted) - {v["name"] for v in variants}
        if unknown:
            raise InputError(f"--only: unknown variant(s) {sorted(unknown)}; known: {[v['name'] for v in variants]}")
        variants = [v for v in variants if v["name"] in wanted]
    base = parse_set_overrides(args.set)
    config = StudyConfig(source=args.scene, budget_minutes=args.budget_minutes, variants=[dict(v) for v in variants],
                         base=base, rank=args.rank)
    results = run_study(config, args.out, progress=not args.quiet)
    best = fastest_within(results, 0.5, args.rank)
    print(open(f"{args.out}/study.md").read())
    if best is not None:
        print(f"fastest within 0.5 dB of the best ({args.rank}): {best.name}")
    return 0
