"""Where a finished run's stage-1 model renders nearer or farther than its dense init's points: on
the train cameras, on a ring of novel cameras around the rig, and on the held-out cameras of
``--val`` (their poses only: no image is read).

    python benchmarks/depth_gap.py RUN [--val SOURCE] [--novel N] [--out FILE.json]

At each of the init's frames, the init's points (static plus the frame's moving ones) are
z-buffered into a camera (``train.depth_prior.point_depth``: the nearest point per pixel, without
the points seen through a nearer surface's holes) and compared with the model's expected depth
where the render is at least half opaque. Per group of cameras: the share of those pixels the
model renders more than ``GAP`` nearer than the init (something in front of the surface the init
measured: fog, a floater) or farther, and the median relative difference. RUN is only read.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

import fixer4d  # noqa: F401  (sets the numerics and the OpenMP wait policy before torch is imported)

sys.path.insert(0, str(Path(__file__).resolve().parent))
from stage1_variants import variant_config  # noqa: E402

# A pixel counts as nearer (farther) when its depth is this fraction in front of (behind) the init's.
GAP = 0.1
# A pixel is compared where the render's opacity reaches this: its depth is the model's surface.
OPAQUE = 0.5


def gaps(model, cameras, frame_points: dict[int, np.ndarray], times: dict[int, float]) -> dict:
    """{"pixels", "nearer", "farther", "median_relative"} over ``cameras`` at the init frames."""
    import torch

    from fixer4d.render.api import render
    from fixer4d.train.depth_prior import DepthPriorConfig, point_depth

    cfg = DepthPriorConfig()
    rel = []
    for f, points in frame_points.items():
        snap = model.at(times[f])
        for cam in cameras:
            z = point_depth(points, cam, cfg.tolerance, cfg.window)
            with torch.no_grad():
                out = render(snap, cam)
            ok = (z > 0) & (out.alpha.numpy() >= OPAQUE)
            rel.append((out.depth.numpy()[ok] - z[ok]) / z[ok])
    r = np.concatenate(rel) if rel else np.zeros(0)
    if r.size == 0:
        return {"pixels": 0, "nearer": None, "farther": None, "median_relative": None}
    return {"pixels": int(r.size), "nearer": float(np.mean(r < -GAP)), "farther": float(np.mean(r > GAP)),
            "median_relative": float(np.median(np.abs(r)))}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path, help="a finished fixer4d run folder (model_stage1.ply, init_mvs/)")
    parser.add_argument("--val", default=None, help="a scene with RUN's train cameras: also its held-out cameras")
    parser.add_argument("--novel", type=int, default=12, help="novel cameras of the ring scored (0: none)")
    parser.add_argument("--out", type=Path, default=None, help="also write the result as JSON")
    args = parser.parse_args(argv)

    from fixer4d.init.decompose import DecomposedInit, has_decomposed
    from fixer4d.model.io import load_ply
    from fixer4d.pipeline.run_folder import load_scene_for
    from fixer4d.train.depth_prior import DepthPriorConfig, NovelDepthViews

    init_dir = args.run / "init_mvs"
    if not has_decomposed(init_dir) or not (args.run / "model_stage1.ply").is_file():
        print(f"{args.run}: no decomposed init_mvs/ or model_stage1.ply; run `fixer4d run` first", file=sys.stderr)
        return 2
    config = variant_config(args.run, [] if args.val is None else [f"scene.source={args.val}"])
    scene = load_scene_for(config)
    init = DecomposedInit.load(init_dir)
    model = load_ply(args.run / "model_stage1.ply").eval()
    novel = NovelDepthViews(init, scene.train_cameras, DepthPriorConfig(novel_weight=1.0))
    points = novel.frame_points  # the static cloud and each init frame's moving points
    times = {f: scene.time(f) for f in points}
    ring = novel.cameras
    step = max(len(ring) // max(args.novel, 1), 1)
    result = {"run": str(args.run), "val": args.val, "gap": GAP, "opaque": OPAQUE, "frames": sorted(points),
              "train": gaps(model, scene.train_cameras, points, times)}
    if args.novel > 0:
        result["novel"] = gaps(model, ring[::step][:args.novel], points, times)
    if args.val is not None:
        result["held_out"] = gaps(model, [scene.cameras[c] for c in scene.test_ids], points, times)
    for group in ("train", "novel", "held_out"):
        if group in result and result[group]["pixels"]:
            g = result[group]
            print(f"{group:9s} {g['pixels']:7d} px: nearer {g['nearer']:.3f}, farther {g['farther']:.3f}, "
                  f"median |relative| {g['median_relative']:.3f}")
    if args.out is not None:
        args.out.write_text(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
