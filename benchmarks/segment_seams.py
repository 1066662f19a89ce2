"""How much a segmented run's picture jumps where playback switches segment.

    python benchmarks/segment_seams.py RUN [--model final|stage1] [--out FILE.json]

RUN is a finished segmented run (`fixer4d run ... --segment-frames F`). At every frame two
neighbouring segments share (their overlap), each held-out camera is rendered by both segments'
models, each at its own local time. The seam PSNR is the PSNR between the two renders: what the
viewer and the evaluation would show differently had the frame been given to the other segment
(higher = a smaller jump; identical renders = inf). It is reported over all pixels and over the
held-out camera's static pixels (the evaluation's rule: its own temporal statistics; metrics only),
beside each render's PSNR against the real frame. RUN is only read.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

import fixer4d  # noqa: F401  (sets the OpenMP wait policy before torch is imported)


def _psnr(a: np.ndarray, b: np.ndarray, mask: np.ndarray | None = None) -> float:
    d = (np.asarray(a, np.float64) - np.asarray(b, np.float64)) ** 2
    if mask is not None:
        d = d[mask]
    mse = float(d.mean()) if d.size else 0.0
    return float("inf") if mse == 0.0 else float(-10.0 * np.log10(mse))


def seams(run: Path, which: str = "final") -> dict:
    from fixer4d.eval.evaluate import heldout_moving_masks
    from fixer4d.model.io import load_ply
    from fixer4d.render.views import model_render_fn
    from fixer4d.train.background import resolve_background
    from fixer4d.pipeline.run_folder import load_scene_for, read_run_config
    from fixer4d.pipeline.segments import segment_dir, split_segments, to_local_time

    config = read_run_config(run)
    if config.segments.frames is None:
        raise SystemExit(f"{run}: not a segmented run (segments.frames is not set)")
    scene = load_scene_for(config)
    ranges = split_segments(scene.num_frames, config.segments.frames, config.segments.overlap)
    names = {"final": "model_final.ply", "stage1": "model_stage1.ply"}
    fns = []
    for k, r in enumerate(ranges):
        d = segment_dir(run, k, r)
        path = d / names[which] if (d / names[which]).is_file() else d / names["stage1"]
        fns.append(model_render_fn(load_ply(path), config.training.backend,
                                   resolve_background(config.training.background, scene)))
    out = []
    for k in range(len(ranges) - 1):
        shared = list(range(ranges[k + 1][0], ranges[k][1]))
        for cam_idx in scene.test_ids:
            cam = scene.cameras[cam_idx]
            moving, _ = heldout_moving_masks(scene, cam_idx, shared)
            for i, f in enumerate(shared):
                t = scene.time(f)
                a = fns[k](cam, to_local_time(t, scene.num_frames, ranges[k]))
                b = fns[k + 1](cam, to_local_time(t, scene.num_frames, ranges[k + 1]))
                gt = scene.frame(f, cam_idx)
                static = ~moving[i]
                out.append({"boundary": k, "frame": f, "camera": cam.name,
                            "seam_psnr": _psnr(a, b), "seam_psnr_static": _psnr(a, b, static),
                            "psnr_before": _psnr(a, gt), "psnr_after": _psnr(b, gt)})
    finite = [r["seam_psnr_static"] for r in out if np.isfinite(r["seam_psnr_static"])]
    return {"run": str(run), "model": which, "ranges": ranges, "share_static": config.segments.share_static,
            "frames": out,
            "mean_seam_psnr": float(np.mean([min(r["seam_psnr"], 99.0) for r in out])) if out else None,
            "mean_seam_psnr_static": float(np.mean([min(r["seam_psnr_static"], 99.0) for r in out])) if out else None,
            "identical_static_frames": len(out) - len(finite)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("run", type=Path)
    ap.add_argument("--model", choices=("final", "stage1"), default="final")
    ap.add_argument("--out", type=Path)
    args = ap.parse_args(argv)
    res = seams(args.run, args.model)
    for r in res["frames"]:
        print(f"boundary {r['boundary']} frame {r['frame']:4d} {r['camera']}: seam {r['seam_psnr']:6.2f} dB "
              f"(static {r['seam_psnr_static']:6.2f}); vs real frame {r['psnr_before']:.2f} | {r['psnr_after']:.2f}")
    print(f"mean seam PSNR {res['mean_seam_psnr']:.2f} dB, static pixels {res['mean_seam_psnr_static']:.2f} dB "
          f"(inf counted as 99)")
    if args.out:
        args.out.write_text(json.dumps(res, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
