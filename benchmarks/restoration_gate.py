"""Where does the restorer help the render, and which gate keeps only that? Per pixel class, on a
run's validation cameras.

    python benchmarks/restoration_gate.py RUN --cameras-from VALIDATION [--stride S] [--out FILE.json]
        [--background-tols 0.02,0.05,0.1,0.2]

RUN is a finished `fixer4d run` folder (its stage-1 model, restorer and config are used as they
are); VALIDATION a folder or bundled spec with the same train cameras and other held-out cameras
(as `fixer4d eval --cameras-from`). For every held-out camera and every S-th frame the camera is
restored exactly as the "Restoration (init)" row restores it (the two nearest train cameras as
references, a three-frame clip through the camera, the middle frame), and the squared error of
these images is summed per pixel class:

- render: the stage-1 render; restored: the restorer's output as it is (the paper's row);
- fill: the render with its unobserved pixels filled from the observed ones at or behind their
  depth (``restore.unobserved_fill.fill_unobserved`` with the render's depth), no restorer;
- fill_plain: the same fill with every boundary pixel weighing the same (no depth);
- fill_tol<T> (with --background-tols): the fill with ``BACKGROUND_DEPTH_TOL`` = T;
- gated: the render + confidence x unobserved x (restored - render), no hole rule;
- gate_render: the gate falling back on the render (``fill=False``: stage 2's gated targets by
  default), holes restored whatever the confidence;
- gate: the gate falling back on the fill (``fill=True``: the Restoration rows by default), the
  restorer by confidence x unobserved;

over the classes all, unobserved (weight > 0.5), hole (alpha < 0.5), unobserved and solid, and
observed. It reads held-out images, so it is a diagnostic of validation cameras: never pass test
cameras to choose a setting with it. Stage 2's targets are ``gate`` by default, ``gate_render`` with
``stage2.fill_unobserved=false`` and ``gated`` with ``stage2.restore_holes=false`` as well.

    python benchmarks/restoration_gate.py --summarize FILE.json ... --out SUMMARY.json

pairs result files over runs (seeds) by their validation folder: per class and image the mean
PSNR and the interval (``fixer4d.stats.interval``) of the image's PSNR minus the render's.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import fixer4d  # noqa: E402,F401  (sets the OpenMP wait policy before torch is imported)

IMAGES = ("render", "restored", "fill_plain", "fill", "gated", "gate_render", "gate")
CLASSES = ("all", "unobserved", "hole", "unobserved_solid", "observed")


def pixel_classes(unobserved: np.ndarray, alpha: np.ndarray) -> dict[str, np.ndarray]:
    hidden = unobserved > 0.5
    return {"all": np.ones_like(hidden), "unobserved": hidden, "hole": alpha < 0.5,
            "unobserved_solid": hidden & (alpha >= 0.5), "observed": ~hidden}


def images(request, result, visibility, tols: tuple[float, ...] = ()) -> dict[str, np.ndarray]:
    """The (H, W, 3) images of the clip's middle frame (both gates are the pipeline's own)."""
    from fixer4d.pipeline.restoration import clip_frame, gate_restoration
    from fixer4d.restore.unobserved_fill import fill_unobserved

    request, result = clip_frame(request, result, 1)
    r, o = request.rgb[0], result.rgb[0]
    conf, hidden = result.confidence[0], request.unobserved[0]
    out = {"render": r, "restored": o, "fill_plain": fill_unobserved(request.rgb, request.unobserved)[0],
           "fill": fill_unobserved(request.rgb, request.unobserved, request.depth, request.alpha)[0],
           "gated": r + (conf * hidden)[..., None] * (o - r),
           "gate_render": gate_restoration(request, result, visibility, fill=False).rgb[0],
           "gate": gate_restoration(request, result, visibility, fill=True).rgb[0]}
    for tol in tols:
        out[f"fill_tol{tol:g}"] = fill_unobserved(request.rgb, request.unobserved, request.depth, request.alpha, tol)[0]
    return out


def summarize(paths: list[Path]) -> dict[str, dict]:
    """Per validation folder (the files' ``cameras_from``), class and image: {"fraction", "render"
    (interval of the render's PSNR), "<image> - render" (interval of the paired differences)}."""
    from fixer4d.stats import interval

    groups: dict[str, list[dict]] = {}
    for path in paths:
        record = json.loads(Path(path).read_text())
        groups.setdefault(Path(record["cameras_from"]).name, []).append(record)
    out: dict[str, dict] = {}
    for name, records in sorted(groups.items()):
        table = {"runs": [r["run"] for r in records]}
        for cls in CLASSES:
            rows = [r["psnr_db"][cls] for r in records]
            entry = {"fraction": interval([r["fraction"] for r in rows])["mean"],
                     "render": interval([r["render"] for r in rows])}
            for image in rows[0]:
                if image not in ("fraction", "render"):
                    entry[f"{image} - render"] = interval([None if r[image] is None or r["render"] is None
                                                           else r[image] - r["render"] for r in rows])
            table[cls] = entry
        out[name] = table
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path, nargs="?")
    parser.add_argument("--summarize", type=Path, nargs="+", metavar="FILE", help="pair result files over runs")
    parser.add_argument("--cameras-from", help="a validation folder or bundled spec")
    parser.add_argument("--stride", type=int, default=6, help="every S-th frame")
    parser.add_argument("--out", type=Path, default=None, help="write the table as JSON")
    parser.add_argument("--background-tols", default="", help="comma-separated BACKGROUND_DEPTH_TOL values to "
                        "add as fill_tol<T> columns")
    args = parser.parse_args(argv)
    if args.summarize:
        summary = summarize(args.summarize)
        for name, table in summary.items():
            print(f"{name} ({len(table['runs'])} runs)")
            for cls in CLASSES:
                e = table[cls]
                if e["render"]["mean"] is None:
                    continue
                diffs = "  ".join(f"{k.split(' ')[0]} {v['mean']:+.2f}±{v['ci95'] or 0:.2f}"
                                  for k, v in e.items() if k.endswith("- render") and v["mean"] is not None)
                print(f"  {cls:17s} {100 * e['fraction']:5.1f} %  render {e['render']['mean']:.2f}  {diffs}")
        if args.out is not None:
            from fixer4d.atomic import write_json

            write_json(args.out, summary)
        return 0
    if args.run is None or args.cameras_from is None:
        parser.error("RUN and --cameras-from are needed (or --summarize FILE ...)")
    tols = tuple(float(t) for t in args.background_tols.split(",") if t.strip())
    names = IMAGES + tuple(f"fill_tol{t:g}" for t in tols)

    from fixer4d.model.io import load_ply
    from fixer4d.pipeline.other_cameras import check_same_train_cameras
    from fixer4d.pipeline.restoration import clip_through, make_request, run_restorer
    from fixer4d.train.background import resolve_background
    from fixer4d.pipeline.run_folder import load_scene_for, read_run_config, source_commit
    from fixer4d.eval.class_psnr import ClassPSNR
    from fixer4d.scene import load_scene

    config = read_run_config(args.run)
    own = load_scene_for(config)
    sc = config.scene
    scene = load_scene(args.cameras_from, scale=sc.scale, frame_range=sc.frame_range)
    check_same_train_cameras(own, scene)
    model = load_ply(args.run / "model_stage1.ply")
    restorer = run_restorer(config, args.run)
    psnr = ClassPSNR(names, CLASSES)
    for cam_idx in scene.test_ids:
        cams, ids = clip_through(scene, scene.cameras[cam_idx])
        for frame in range(0, scene.num_frames, args.stride):
            request = make_request(model, scene, cams, frame, ids, visibility=config.stage2.visibility,
                                   background=resolve_background(config.training.background, scene))
            result = restorer.restore(request)
            psnr.add(scene.frame(frame, cam_idx), images(request, result, config.stage2.visibility, tols),
                     pixel_classes(request.unobserved[1], request.alpha[1]))
    psnr.report(args.out, run=str(args.run), cameras_from=str(args.cameras_from), stride=args.stride,
                restorer=config.restorer.kind, commit=source_commit())
    return 0


if __name__ == "__main__":
    sys.exit(main())
