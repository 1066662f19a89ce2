"""Does the Real-ESRGAN prior (``restore/sr_prior.py``) improve the restored images? Per pixel class,
on the validation cameras of paired runs (one per seed), PSNR and LPIPS with and without it.

    python benchmarks/sr_prior.py RUN [RUN ...] --cameras-from VALIDATION [--stride S]
        [--models realesrgan-x4plus,realesr-animevideov3-x2] [--out FILE.json]

Each RUN is a `fixer4d run` folder with its stage-1 model (``model_stage1.ply``) and config; the runs
differ by seed only, so each run gives one pair (with / without the prior). For every held-out camera
of VALIDATION and every S-th frame the camera is restored as the "Restoration (init)" row restores it
(``benchmarks/restoration_gate.py``: the middle frame of a three-frame clip through the camera), then
scored as three images, each without the prior and with each model's prior
(``sr_prior.apply_prior`` at strength 1 on that frame; the prior works frame by frame, so this is
what ``SRPriorRestorer`` gives for the frame):

- restored: the restorer's output as it is;
- gate: ``gate_restoration`` with the unobserved fill (the Restoration rows' image);
- gate_render: ``gate_restoration`` falling back on the render (stage 2's gated targets);

over the pixel classes all, unobserved, hole and observed. PSNR pools the squared error over a
class (``ClassPSNR``); LPIPS is LPIPS-alex's spatial map (each layer's distance map upsampled to the
image, summed) averaged over the class's pixels. The paired gain of each column is the mean over
runs of (with − without) with its 95 % interval (``fixer4d.stats.interval``). It reads held-out
images: pass validation cameras only, never test cameras.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import fixer4d  # noqa: E402,F401  (sets the OpenMP wait policy before torch is imported)
from benchmarks.restoration_gate import pixel_classes  # noqa: E402

IMAGES = ("restored", "gate", "gate_render")
CLASSES = ("all", "unobserved", "hole", "observed")
NONE = "none"


def lpips_map(module, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(H, W) LPIPS-alex distance map of two (H, W, 3) images in [0, 1]: each layer's
    normalized feature distance (its linear head) upsampled bilinearly to (H, W), summed; its mean
    is LPIPS (up to the upsampling)."""
    import torch
    import torch.nn.functional as F

    from fixer4d.eval.lpips import NORMALIZE_EPS

    def feats(img: np.ndarray):
        x = torch.from_numpy(np.ascontiguousarray(img, dtype=np.float32)).permute(2, 0, 1)[None] * 2.0 - 1.0
        return module.features((x - module.shift) / module.scale)

    H, W = a.shape[:2]
    total = torch.zeros(1, 1, H, W)
    with torch.no_grad():
        for fa, fb, lin in zip(feats(a), feats(b), module.lins):
            fa = fa / (fa.pow(2).sum(dim=1, keepdim=True).sqrt() + NORMALIZE_EPS)
            fb = fb / (fb.pow(2).sum(dim=1, keepdim=True).sqrt() + NORMALIZE_EPS)
            total += F.interpolate(lin((fa - fb) ** 2), size=(H, W), mode="bilinear", align_corners=False)
    return total[0, 0].numpy()


def score_run(run: Path, cameras_from: str, stride: int, models: tuple[str, ...], lpips) -> dict:
    """{"psnr_db": {class: {column: dB}}, "lpips": {class: {column: mean}}, "images", "seconds"} of
    one run; columns are ``<image>:<variant>`` with variant ``none`` or a model name."""
    from fixer4d.eval.class_psnr import ClassPSNR
    from fixer4d.model.io import load_ply
    from fixer4d.pipeline.other_cameras import check_same_train_cameras
    from fixer4d.pipeline.restoration import clip_frame, clip_through, gate_restoration, make_request, run_restorer
    from fixer4d.train.background import resolve_background
    from fixer4d.pipeline.run_folder import load_scene_for, read_run_config
    from fixer4d.restore.sr_prior import RealESRGANPrior, SRPriorConfig, apply_prior
    from fixer4d.scene import load_scene

    config = read_run_config(run)
    sc = config.scene
    scene = load_scene(cameras_from, scale=sc.scale, frame_range=sc.frame_range)
    check_same_train_cameras(load_scene_for(config), scene)
    model = load_ply(run / "model_stage1.ply")
    restorer = run_restorer(config, run)
    vis = config.stage2.visibility
    priors = {m: RealESRGANPrior(SRPriorConfig(enabled=True, model=m)) for m in models}
    columns = [f"{i}:{v}" for i in IMAGES for v in (NONE,) + models]
    psnr = ClassPSNR(columns, CLASSES)
    lp_sum = {c: dict.fromkeys(columns, 0.0) for c in CLASSES}
    lp_count = dict.fromkeys(CLASSES, 0)
    start, n = time.perf_counter(), 0
    for cam_idx in scene.test_ids:
        cams, ids = clip_through(scene, scene.cameras[cam_idx])
        for frame in range(0, scene.num_frames, stride):
            request = make_request(model, scene, cams, frame, ids, visibility=vis,
                                   background=resolve_background(config.training.background, scene))
            request, result = clip_frame(request, restorer.restore(request), 1)
            variants = {NONE: result, **{m: apply_prior(result, p) for m, p in priors.items()}}
            images = {}
            for v, res in variants.items():
                images[f"restored:{v}"] = res.rgb[0]
                images[f"gate:{v}"] = gate_restoration(request, res, vis, fill=True).rgb[0]
                images[f"gate_render:{v}"] = gate_restoration(request, res, vis, fill=False).rgb[0]
            truth = scene.frame(frame, cam_idx)
            masks = {k: m for k, m in pixel_classes(request.unobserved[0], request.alpha[0]).items() if k in CLASSES}
            psnr.add(truth, images, masks)
            maps = {k: lpips_map(lpips, np.clip(img, 0.0, 1.0), truth) for k, img in images.items()}
            for c, mask in masks.items():
                lp_count[c] += int(mask.sum())
                for k in columns:
                    lp_sum[c][k] += float(maps[k][mask].sum())
            n += 1
    lp = {c: {k: (lp_sum[c][k] / lp_count[c] if lp_count[c] else None) for k in columns} for c in CLASSES}
    return {"run": str(run), "images": n, "seconds": time.perf_counter() - start, "psnr_db": psnr.table(),
            "lpips": lp}


def paired(per_run: list[dict], models: tuple[str, ...]) -> dict:
    """{metric: {class: {"<image>:<model>": interval of (with − without) over runs}}}."""
    from fixer4d.stats import interval

    out: dict = {}
    for metric in ("psnr_db", "lpips"):
        out[metric] = {}
        for c in CLASSES:
            row = {}
            for i in IMAGES:
                for m in models:
                    diffs = [r[metric][c][f"{i}:{m}"] - r[metric][c][f"{i}:{NONE}"] for r in per_run
                             if r[metric][c][f"{i}:{m}"] is not None and r[metric][c][f"{i}:{NONE}"] is not None]
                    row[f"{i}:{m}"] = interval(diffs)
            out[metric][c] = row
    return out


def wins(gains: dict) -> list[str]:
    """The (metric, class, column) whose paired 95 % interval excludes zero in the prior's favour:
    PSNR gain above 0, LPIPS change below 0."""
    found = []
    for metric, sign in (("psnr_db", 1.0), ("lpips", -1.0)):
        for c, row in gains[metric].items():
            for col, iv in row.items():
                if iv["ci95"] is not None and sign * iv["mean"] - iv["ci95"] > 0:
                    found.append(f"{metric} {c} {col}")
    return found


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", type=Path, nargs="+", help="run folders, one per seed")
    parser.add_argument("--cameras-from", required=True, help="a validation folder or bundled spec")
    parser.add_argument("--stride", type=int, default=5, help="every S-th frame")
    parser.add_argument("--models", default="realesrgan-x4plus,realesr-animevideov3-x2",
                        help="comma-separated sr_prior models (restore.sr_prior.MODELS)")
    parser.add_argument("--out", type=Path, default=None, help="write the figures as JSON")
    args = parser.parse_args(argv)
    models = tuple(m.strip() for m in args.models.split(",") if m.strip())

    from fixer4d.eval.lpips import LPIPSAlex, find_weights
    from fixer4d.pipeline.run_folder import source_commit
    from fixer4d.restore.sr_prior import MODELS, unavailable_reason

    unknown = [m for m in models if m not in MODELS]
    if unknown:
        parser.error(f"unknown model(s) {unknown}; choose from {', '.join(MODELS)}")
    reason = unavailable_reason()
    if reason is not None:
        print(f"sr_prior: Real-ESRGAN unavailable: {reason}", file=sys.stderr)
        return 1
    lpips = LPIPSAlex.from_checkpoint(find_weights())
    per_run = []
    for run in args.runs:
        record = score_run(run, args.cameras_from, args.stride, models, lpips)
        per_run.append(record)
        print(f"{run}: {record['images']} images, {record['seconds']:.0f} s", flush=True)
        for c in CLASSES:
            p, lp = record["psnr_db"][c], record["lpips"][c]
            print(f"  {c:10s} {100 * p['fraction']:5.1f} % " + " ".join(
                f"{k} {p[k]:.2f}/{lp[k]:.4f}" for k in p if k != "fraction" and p[k] is not None))
    gains = paired(per_run, models)
    won = wins(gains)
    for metric in ("psnr_db", "lpips"):
        for c in CLASSES:
            print(f"paired {metric} {c:10s} " + " ".join(
                f"{k} {iv['mean']:+.4f}±{iv['ci95'] if iv['ci95'] is not None else float('nan'):.4f}"
                for k, iv in gains[metric][c].items() if iv["mean"] is not None))
    print("wins by the paired interval:", ", ".join(won) if won else "none")
    if args.out is not None:
        from fixer4d.atomic import write_json

        write_json(args.out, {"cameras_from": args.cameras_from, "stride": args.stride, "models": list(models),
                              "strength": 1.0, "commit": source_commit(), "runs": per_run, "paired_gain": gains,
                              "wins": won})
    return 0


if __name__ == "__main__":
    sys.exit(main())
