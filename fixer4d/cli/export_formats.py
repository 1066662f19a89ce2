"""`fixer4d export ... --format ply-sequence|splatv`: the viewer formats (docs/output.md).

ply-sequence: one 3DGS PLY per frame plus manifest.json (``fixer4d.model.formats.ply_sequence``).
splatv: splaTV's single file (``fixer4d.model.formats.splatv``), with the reduction error (PSNR of
the file's content against the model, both rendered by fixer4d) printed and saved beside it as
FILE.splatv.json.
"""
from __future__ import annotations

import argparse
from pathlib import Path

from fixer4d.errors import InputError

# Default frame rate of a sequence when neither --fps nor a run's scene gives one.
DEFAULT_FPS = 30.0
# Times at which the splatv reduction error is sampled: centres of 5 equal parts of the clip, so
# neither end (where a clip's first/last Gaussians fade) is over- or under-weighted.
ERROR_TIMES = tuple((k + 0.5) / 5 for k in range(5))


def _progress(total: int, desc: str, quiet: bool):
    from tqdm import tqdm

    bar = tqdm(total=total, desc=desc, unit="frame", disable=quiet)

    def update(done: int, _total: int) -> None:
        bar.update(done - bar.n)
        if done == _total:
            bar.close()

    return update


def _ply_sequence(args: argparse.Namespace, src) -> int:
    from fixer4d.model.formats.ply_sequence import export_ply_sequence
    from fixer4d.cli.output_source import clip_times
    from fixer4d.render.constants import ALPHA_MIN

    if args.frames is None and src.config is None:
        raise InputError(f"{src.model_path}: a bare model file has no frame count; pass --frames N (and --fps)")
    frames = args.frames if args.frames is not None else src.scene.num_frames
    fps = args.fps if args.fps is not None else (src.scene.fps if src.config is not None else DEFAULT_FPS)
    min_opacity = ALPHA_MIN if args.min_opacity is None else args.min_opacity
    if not 0.0 <= min_opacity < 1.0:
        raise InputError(f"--min-opacity must be in [0, 1), got {min_opacity}")
    model = src.model
    manifest = export_ply_sequence(model, args.out, clip_times(frames), fps=fps, min_opacity=min_opacity,
                                   progress=_progress(frames, "ply-sequence", args.quiet))
    print(f"{src.model_path} -> {Path(args.out)}/: {frames} frames at {fps:g} fps ({model.num_gaussians} Gaussians, "
          f"{model.num_dynamic} dynamic), {manifest.name}")
    return 0


def _splatv(args: argparse.Namespace, src) -> int:
    from fixer4d.atomic import write_json
    from fixer4d.eval.format_fidelity import reduction_psnr
    from fixer4d.model.formats import splatv
    from fixer4d.cli.output_source import framing_camera

    if args.frames is not None or args.fps is not None or args.min_opacity is not None:
        raise InputError("--frames/--fps/--min-opacity apply to --format ply-sequence; a .splatv holds the whole clip")
    model = src.model
    cameras = src.scene.train_cameras if src.config is not None else [framing_camera(model)]
    fields = splatv.reduce(model)
    out = splatv.write_splatv(fields, args.out, cameras)
    reduced = splatv.to_model(fields)
    error = reduction_psnr(model, lambda t: splatv.snapshot_at(reduced, fields, t), cameras, ERROR_TIMES,
                           background=src.background)
    report = {"file": str(out), "model": str(src.model_path), "gaussians": len(fields),
              "dropped_transparent": model.num_gaussians - len(fields), "clipped_values": fields.clipped, **error}
    write_json(out.with_name(out.name + ".json"), report)
    print(f"{src.model_path} -> {out}: {len(fields)} Gaussians ({report['dropped_transparent']} with 8-bit opacity 0 "
          f"left out, {fields.clipped} values clipped to float16), {out.stat().st_size / 2 ** 20:.1f} MiB")
    print(f"reduction error: PSNR {error['psnr_mean']:.2f} dB mean, {error['psnr_min']:.2f} dB worst over "
          f"{len(error['samples'])} renders (fixer4d's renderer, format vs model; {out.name}.json)")
    return 0


def run(args: argparse.Namespace, fmt: str, model_path: Path) -> int:
    """Export ``model_path`` (resolved from args.source by the export verb) as ``fmt``."""
    from fixer4d.cli.output_source import open_source

    src = open_source(args.source, model_path)
    if fmt == "ply-sequence":
        return _ply_sequence(args, src)
    if fmt == "splatv":
        return _splatv(args, src)
    raise InputError(f"--format {fmt!r}: unknown; choose model, ply-sequence or splatv")
