"""What limits the geometric restorer: the model's depth. Restore the held-out views of a finished
synthetic run with the model's own depth and with the true depth, and compare with the render.

    python benchmarks/restorer_depth.py RUN [--frames 0,10] [--out FILE.json]

For every held-out camera h of RUN's scene and every given frame, the restore request of the
"Restoration (init)" row is built exactly as the pipeline builds it (the two train cameras nearest
to h are the references, the other two extra views; `pipeline.restoration.make_request`) from
RUN/model_stage1.ply, and RUN's configured warp restorer is run twice: once on the request as it
is (the model's depth at h and at the references), once with every depth replaced by the scene's
ray-cast truth (alpha 1). The gap between the two is what better geometry would give the warp
restorer; the gap between the render and the first is what it gives today.

A diagnostic that reads ground truth: it lives here, never in the method, and nothing it
produces feeds a run.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

import fixer4d  # noqa: F401  (sets the OpenMP wait policy before torch is imported)


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    return float(-10.0 * np.log10(max(float(np.mean((np.asarray(a) - np.asarray(b)) ** 2)), 1e-12)))


def true_depth_request(request, scene):
    """A copy of ``request`` whose depths (novel frames, references, extra views) are the truth."""
    import copy

    req = copy.copy(request)
    req.depth = np.stack([scene.render_gt(c, request.time)[1] for c in request.cameras]).astype(np.float32)
    req.alpha = np.ones_like(request.alpha)
    req.ref_depths = [scene.render_gt(c, request.time)[1].astype(np.float32) for c in request.ref_cameras]
    req.ref_alphas = [np.ones_like(a) for a in request.ref_alphas]
    if request.extra_cameras:
        req.extra_depths = [scene.render_gt(c, request.time)[1].astype(np.float32) for c in request.extra_cameras]
    return req


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path, help="a finished fixer4d run folder of a synthetic scene")
    parser.add_argument("--frames", default="0,10", help="comma-separated frames (default 0,10)")
    parser.add_argument("--out", type=Path, default=None, help="write the per-view figures as JSON")
    args = parser.parse_args(argv)

    from fixer4d.model.io import load_ply
    from fixer4d.pipeline.restoration import make_request
    from fixer4d.train.background import resolve_background
    from fixer4d.pipeline.run_folder import load_scene_for, read_run_config
    from fixer4d.restore.reference_warp import ReferenceWarpRestorer

    config = read_run_config(args.run)
    scene = load_scene_for(config)
    if not hasattr(scene, "render_gt"):
        raise SystemExit("restorer_depth: the run's scene has no ground truth (synthetic scenes only)")
    model = load_ply(args.run / "model_stage1.ply")
    restorer = ReferenceWarpRestorer(config.restorer.warp)
    frames = [int(f) for f in args.frames.split(",")]
    rows = []
    for h in scene.test_ids:
        cam = scene.cameras[h]
        order = np.argsort([np.linalg.norm(scene.cameras[i].center - cam.center) for i in scene.train_ids])
        refs = (scene.train_ids[order[0]], scene.train_ids[order[1]])
        for f in frames:
            req = make_request(model, scene, [cam], f, refs, backend=config.training.backend,
                               background=resolve_background(config.training.background, scene))
            truth, true_depth = scene.render_gt(cam, req.time)
            model_depth = req.depth[0]
            rel = np.abs(model_depth - true_depth) / np.maximum(true_depth, 1e-9)
            rows.append({"camera": cam.name, "frame": f, "references": [scene.cameras[i].name for i in refs],
                         "psnr_render": psnr(req.rgb[0], truth),
                         "psnr_warp_model_depth": psnr(restorer.restore(req).rgb[0], truth),
                         "psnr_warp_true_depth": psnr(restorer.restore(true_depth_request(req, scene)).rgb[0], truth),
                         "model_depth_median_rel_error": float(np.median(rel)),
                         "model_depth_within_1pct": float(np.mean(rel < 0.01))})
    keys = ("psnr_render", "psnr_warp_model_depth", "psnr_warp_true_depth", "model_depth_median_rel_error",
            "model_depth_within_1pct")
    mean = {k: float(np.mean([r[k] for r in rows])) for k in keys}
    print("| held-out views | render | warp, model depth | warp, true depth | model depth: median rel. error | within 1 % |")
    print("|---|---|---|---|---|---|")
    print(f"| {len(rows)} | {mean['psnr_render']:.2f} | {mean['psnr_warp_model_depth']:.2f} | "
          f"{mean['psnr_warp_true_depth']:.2f} | {mean['model_depth_median_rel_error']:.4f} | "
          f"{mean['model_depth_within_1pct']:.2f} |")
    if args.out is not None:
        args.out.write_text(json.dumps({"run": str(args.run), "mean": mean, "views": rows}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
