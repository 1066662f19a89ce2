"""`fixer4d init SCENE --method sparse|mvs|both --out DIR [--frames a:b] ...`

Writes frame_XXXX.ply per frame and init_report.json to DIR. ``--method both`` runs the sparse
baseline and MVS on the same frames into DIR/sparse and DIR/mvs and writes DIR/compare.json
with the preparation-time ratio and both clouds' quality side by side.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path


def parse_frames(text: str | None) -> list[int] | None:
    """"a:b" (half-open), "a:b:s" or "a,b,c" -> frame list; None -> None (all frames)."""
    from fixer4d.errors import InputError

    if text is None:
        return None
    try:
        if ":" in text:
            parts = [int(p) for p in text.split(":")]
            if len(parts) not in (2, 3):
                raise ValueError
            return list(range(*parts))
        frames = [int(p) for p in text.split(",") if p.strip()]
    except ValueError:
        raise InputError(f"--frames {text!r}: use a:b (half-open range), a:b:step or a comma list like 0,5,10") from None
    twice = sorted({f for f in frames if frames.count(f) > 1})
    if twice:
        raise InputError(f"--frames {text!r}: frame(s) {twice} listed twice; list each frame once")
    return frames


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("scene", help="'demo', a synthetic spec .json, or a scene folder (Neural3DV / Panoptic)")
    parser.add_argument("--method", choices=["sparse", "mvs", "both"], default="mvs",
                        help="sparse = COLMAP triangulation baseline; mvs = multi-view stereo + fusion; both = compare")
    parser.add_argument("--out", required=True, help="output folder (frame_XXXX.ply + init_report.json)")
    parser.add_argument("--frames", default=None, help="frames a:b (half-open), a:b:step or a,b,c (default: all)")
    parser.add_argument("--poses", choices=["given", "sfm"], default="given",
                        help="camera poses: the scene's own (default) or pycolmap SfM on the train views at t=0")
    parser.add_argument("--check-poses", action="store_true",
                        help="with --poses given, also run SfM and report its pose error against the given poses")
    parser.add_argument("--estimator", choices=["planesweep", "mvsanywhere"], default="planesweep",
                        help="depth estimator for --method mvs")
    parser.add_argument("--planes", type=int, default=None, help="plane-sweep depth hypotheses (default 128)")
    parser.add_argument("--mvs-scale", type=float, default=None, help="plane-sweep working resolution scale (default 1)")
    parser.add_argument("--scale", type=float, default=1.0, help="scene image scale when loading (0.5 = half)")
    parser.add_argument("--no-quality", action="store_true", help="skip the ground-truth comparison")
    parser.add_argument("--quiet", action="store_true", help="no progress bars")


def build_config(args: argparse.Namespace):
    from fixer4d.init.run import InitConfig

    config = InitConfig()
    config.estimator = args.estimator
    config.quality = not args.no_quality
    config.poses.source = args.poses
    config.poses.check = bool(args.check_poses)
    if args.planes is not None:
        config.mvs.planes = int(args.planes)
    if args.mvs_scale is not None:
        config.mvs.scale = float(args.mvs_scale)
    config.mvs.check()
    return config


def _fmt(x, spec: str) -> str:
    return "-" if x is None else format(x, spec)


def summary_table(reports: dict[str, dict]) -> str:
    """A markdown table of the headline numbers of one or more init reports."""
    rows = ["| method | frames | points/frame | prep. s | s/frame | accuracy | completeness | depth abs-rel | <1% | <5% | valid | coverage |",
            "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for name, rep in reports.items():
        q = rep.get("quality") or {}
        n = len(rep["frames"])
        prep = rep["seconds"].get("preparation", rep["seconds"]["total"])
        rows.append(f"| {name} | {n} | {sum(rep['points_per_frame']) / n:.0f} | {prep:.1f} | {prep / n:.2f} | "
                    f"{_fmt(q.get('accuracy'), '.4f')} | {_fmt(q.get('completeness'), '.3f')} | "
                    f"{_fmt(q.get('depth_abs_rel'), '.4f')} | {_fmt(q.get('depth_within_1pct'), '.3f')} | "
                    f"{_fmt(q.get('depth_within_5pct'), '.3f')} | {_fmt(q.get('valid_share'), '.3f')} | "
                    f"{_fmt(q.get('coverage'), '.3f')} |")
    return "\n".join(rows)


def run(args: argparse.Namespace) -> int:
    from fixer4d.atomic import write_json
    from fixer4d.init.run import run_init
    from fixer4d.scene import load_scene

    config = build_config(args)
    scene = load_scene(args.scene, scale=args.scale)
    frames = parse_frames(args.frames)
    out = Path(args.out)
    methods = ["sparse", "mvs"] if args.method == "both" else [args.method]
    reports = {}
    for method in methods:
        target = out / method if args.method == "both" else out
        _, reports[method] = run_init(scene, method, target, frames=frames, config=config, progress=not args.quiet)
    print(scene.describe())
    print(summary_table(reports))
    for method, rep in reports.items():
        if not any(rep["points_per_frame"]):
            print(f"warning: {method} found no point in any frame"
                  + (" (textureless images, or a --mvs-scale too small to match)" if method == "mvs" else "")
                  + "; training from it starts from random points", file=sys.stderr)
    for method, rep in reports.items():
        pe = rep.get("pose_error")
        if pe and "error" not in pe:
            print(f"{method}: SfM pose error vs given: rotation {pe['rotation_deg_mean']:.3f} deg mean "
                  f"({pe['rotation_deg_max']:.3f} max), centre {pe['center_error_rel_mean']:.4f} x rig radius")
            break
        if pe:
            print(f"{method}: SfM pose check failed: {pe['error']}")
            break
    if args.method == "both":
        sp, mv = reports["sparse"]["seconds"]["preparation"], reports["mvs"]["seconds"]["preparation"]
        sp_cpu, mv_cpu = (reports[m]["cpu_seconds"]["preparation"] for m in ("sparse", "mvs"))
        compare = {"scene": args.scene, "frames": reports["mvs"]["frames"],
                   "preparation_seconds": {"sparse": sp, "mvs": mv},
                   "sparse_over_mvs_time": sp / mv if mv > 0 else None,
                   "preparation_cpu_seconds": {"sparse": sp_cpu, "mvs": mv_cpu},
                   "sparse_over_mvs_cpu_time": sp_cpu / mv_cpu if mv_cpu > 0 else None,
                   "points_per_frame": {m: r["points_per_frame"] for m, r in reports.items()},
                   "quality": {m: r["quality"] for m, r in reports.items()},
                   "pose_error": reports["sparse"].get("pose_error")}
        write_json(out / "compare.json", compare)
        print(f"preparation time sparse / mvs = {compare['sparse_over_mvs_time']:.2f} "
              f"({sp:.1f} s vs {mv:.1f} s wall, {sp_cpu:.1f} s vs {mv_cpu:.1f} s CPU, for "
              f"{len(compare['frames'])} frames); written {out / 'compare.json'}")
    return 0
