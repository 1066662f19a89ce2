"""`fixer4d export MODEL_OR_RUN --out FILE.ply|.npz|DIR|FILE.splatv`: convert a model file, or a
run's latest model, to fixer4d's formats or a viewer's (``--format``, docs/output.md).

A run folder's latest model is model_final.ply (after stage 2), else model_stage1.ply.
"""
from __future__ import annotations

import argparse
from pathlib import Path

# Latest first: stage 2's output supersedes stage 1's (run folder contract).
RUN_MODELS = ("model_final.ply", "model_stage1.ply")
EXPORT_FORMATS = ("model", "ply-sequence", "splatv")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("source", metavar="MODEL_OR_RUN", help="a .ply/.npz model or a run folder (runs/<name>)")
    parser.add_argument("--out", required=True,
                        help="output: a .ply/.npz model (the extension picks it), a folder (--format ply-sequence) "
                             "or a .splatv file")
    parser.add_argument("--format", choices=EXPORT_FORMATS, default=None,
                        help="model: fixer4d .ply/.npz (default for those extensions); ply-sequence: one 3DGS PLY "
                             "per frame + manifest.json; splatv: splaTV's single file (default for .splatv)")
    parser.add_argument("--frames", type=int, default=None,
                        help="ply-sequence: frames to write (default: the run's scene frame count)")
    parser.add_argument("--fps", type=float, default=None, help="ply-sequence: frame rate in the manifest "
                                                                 "(default: the scene's, else 30)")
    parser.add_argument("--min-opacity", type=float, default=None,
                        help="ply-sequence: drop Gaussians whose opacity at the frame is below this "
                             "(default 1/255, the smallest alpha the rasterizers blend)")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


def missing_model_message(run: Path, names: tuple[str, ...] = RUN_MODELS) -> str:
    """Why ``run`` has none of ``names``, and what to do: a segmented run (``--segment-frames``)
    keeps one run folder per segment under RUN/segments/; any other run has not trained yet."""
    segments = sorted(p for p in (run / "segments").glob("seg*") if p.is_dir()) if (run / "segments").is_dir() else []
    if segments:
        return (f"{run}: a segmented run: each segment is its own run folder with its models "
                f"({', '.join(p.name for p in segments[:3])}{', ...' if len(segments) > 3 else ''} under "
                f"{run / 'segments'}); pass one of those, e.g. {segments[0]}")
    return f"{run}: run folder without a model ({' or '.join(names)}); run `fixer4d reconstruct` (or `fixer4d run`) first"


def resolve_model_path(source: str | Path) -> Path:
    """A model file as given, or the latest model inside a run folder."""
    from fixer4d.errors import InputError

    path = Path(source)
    if path.is_dir():
        for name in RUN_MODELS:
            if (path / name).is_file():
                return path / name
        raise InputError(missing_model_message(path))
    return path


def export_format(args: argparse.Namespace) -> str:
    """--format, or the one --out's extension implies (.ply/.npz: model, .splatv: splatv)."""
    from fixer4d.errors import InputError

    if args.format is not None:
        return args.format
    suffix = Path(args.out).suffix.lower()
    if suffix in (".ply", ".npz"):
        return "model"
    if suffix == ".splatv":
        return "splatv"
    raise InputError(f"--out {args.out}: no format for {suffix or 'a name without extension'!r}; pass "
                     "--format ply-sequence (a folder), end it in .splatv, .ply or .npz")


def run(args: argparse.Namespace) -> int:
    from fixer4d.model.io import load_model, save_model

    fmt = export_format(args)
    src = resolve_model_path(args.source)
    if fmt != "model":
        from fixer4d.cli import export_formats

        return export_formats.run(args, fmt, src)
    model = load_model(src)
    out = save_model(model, args.out)
    print(f"{src} -> {out}: {model.num_gaussians} Gaussians ({model.num_dynamic} dynamic), "
          f"config {model.config.to_dict()}")
    return 0
