"""`fixer4d export MODEL_OR_RUN --out FILE.ply|.npz`: convert a model file, or a run's latest model.

A run folder's latest model is model_final.ply (after stage 2), else model_stage1.ply.
"""
from __future__ import annotations

import argparse
from pathlib import Path

# Latest first: stage 2's output supersedes stage 1's (run folder contract).
RUN_MODELS = ("model_final.ply", "model_stage1.ply")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("source", metavar="MODEL_OR_RUN", help="a .ply/.npz model or a run folder (runs/<name>)")
    parser.add_argument("--out", required=True, help="output file; the extension (.ply or .npz) picks the format")


def resolve_model_path(source: str | Path) -> Path:
    """A model file as given, or the latest model inside a run folder."""
    from fixer4d.errors import InputError

    path = Path(source)
    if path.is_dir():
        for name in RUN_MODELS:
            if (path / name).is_file():
                return path / name
        raise InputError(f"{path}: run folder without a model ({' or '.join(RUN_MODELS)}); "
                         "run `fixer4d reconstruct` first")
    return path


def run(args: argparse.Namespace) -> int:
    from fixer4d.model.io import load_model, save_model

    src = resolve_model_path(args.source)
    model = load_model(src)
    out = save_model(model, args.out)
    print(f"{src} -> {out}: {model.num_gaussians} Gaussians ({model.num_dynamic} dynamic), "
          f"config {model.config.to_dict()}")
    return 0
