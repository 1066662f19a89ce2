"""The Gaussians no train camera sees: what they do to the self-check's held-back camera and to a
run's held-out cameras.

    python benchmarks/fold_unseen.py RUN [--val SOURCE] [--png FILE] [--out FILE.json]

The opacity decay fades only the Gaussians whose centre a step's views see
(``train.opacity_decay.seen_by``), so a Gaussian whose centre lies outside every train camera's
view keeps its opacity, however large its footprint. This scores, on RUN's finished self-check
fold (``RUN/self_check/model_stage1.ply``, its held-back camera, the fold's scale and scored
frames), the fold's model as it is and with those Gaussians removed (opacity logit −30), and
counts them and their opacities. ``--val SOURCE`` does the same for RUN's stage-1 model on the
held-out cameras of SOURCE (a scene with RUN's train cameras; every ``eval.stride``-th frame) with
the Gaussians no train camera of the run sees. ``--png`` saves the held-back camera's first scored
frame: the fold's render, the render without them, the recording. RUN is only read.
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

# An opacity logit that renders nothing (sigmoid(-30) ~ 1e-13): the Gaussian is removed.
REMOVED_LOGIT = -30.0


def _unseen(model, cameras) -> "np.ndarray":
    """(N,) bool: the Gaussians whose centre none of ``cameras`` sees (``seen_by``, the decay's test)."""
    from fixer4d.train.model_init import scene_extent
    from fixer4d.train.opacity_decay import seen_by

    means = model.means.detach()
    return (~seen_by(means, cameras, scene_extent(cameras, means))).numpy()


def _without(model, unseen: np.ndarray):
    """A copy of ``model`` with the ``unseen`` rows' opacity at REMOVED_LOGIT."""
    import copy

    import torch

    out = copy.deepcopy(model)
    with torch.no_grad():
        out.opacity_logits[torch.from_numpy(unseen)] = REMOVED_LOGIT
    return out


def _census(model, unseen: np.ndarray) -> dict:
    import torch

    opacity = torch.sigmoid(model.opacity_logits.detach()).numpy()[unseen]
    return {"gaussians": int(unseen.size), "unseen": int(unseen.sum()),
            "unseen_opacity_quantiles": ({str(q): float(np.quantile(opacity, q)) for q in (0.1, 0.5, 0.9)}
                                         if opacity.size else None),
            "unseen_above_half": int((opacity > 0.5).sum())}


def _psnr(model, view, cameras: list[int], frames: list[int], backend: str, background) -> float:
    """Mean PSNR (dB) of ``model`` over ``cameras`` x ``frames`` of ``view``."""
    from fixer4d.eval.metrics import psnr
    from fixer4d.render.views import render_views

    values = [float(psnr(render_views(model, [view.cameras[c]], view.time(f), backend, background)[0][0],
                         view.frame(f, c))) for c in cameras for f in frames]
    return float(np.mean(values))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path, help="a finished fixer4d run folder with a self-check")
    parser.add_argument("--val", default=None, help="also score the stage-1 model on this source's held-out cameras")
    parser.add_argument("--png", type=Path, default=None, help="save the held-back camera's renders beside its frame")
    parser.add_argument("--out", type=Path, default=None, help="also write the result as JSON")
    args = parser.parse_args(argv)

    import torch

    from fixer4d.model.io import load_ply
    from fixer4d.pipeline.run_folder import load_scene_for, read_run_config
    from fixer4d.scene.train_view import TrainOnlyView
    from fixer4d.train.background import resolve_background

    decision_file = args.run / "self_check" / "decision.json"
    if not decision_file.is_file():
        raise SystemExit(f"{args.run}: no finished self-check (self_check/decision.json); run `fixer4d run` to the end")
    config = read_run_config(args.run)
    scene = load_scene_for(config)
    decision = json.loads(decision_file.read_text())
    held, fold_ids = int(decision["held_back_camera"]), [int(c) for c in decision["fold_cameras"]]
    scored = TrainOnlyView(scene, fold_ids, config.self_check.scale)
    background = torch.tensor(resolve_background(config.training.background, scored), dtype=torch.float32)
    backend = config.training.backend
    fold_model = load_ply(args.run / "self_check" / "model_stage1.ply")
    unseen = _unseen(fold_model, [scored.cameras[c] for c in fold_ids])
    cut = _without(fold_model, unseen)
    frames = [int(f) for f in decision["frames"]]
    result = {"run": str(args.run), "fold": {
        "held_back_camera": held, "fold_cameras": fold_ids, "frames": frames, **_census(fold_model, unseen),
        "psnr": _psnr(fold_model, scored, [held], frames, backend, background),
        "psnr_without_unseen": _psnr(cut, scored, [held], frames, backend, background)}}
    print(f"fold: {result['fold']['unseen']} of {result['fold']['gaussians']} Gaussians unseen by the fold's cameras; "
          f"held-back camera {result['fold']['psnr']:.2f} dB, {result['fold']['psnr_without_unseen']:.2f} without them")
    if args.png is not None:
        from fixer4d.render.views import render_views
        from PIL import Image

        row = [render_views(m, [scored.cameras[held]], scored.time(frames[0]), backend, background)[0][0]
               for m in (fold_model, cut)] + [scored.frame(frames[0], held)]
        image = np.clip(np.concatenate([np.asarray(x, dtype=np.float32) for x in row], axis=1), 0.0, 1.0)
        Image.fromarray((image * 255 + 0.5).astype(np.uint8)).save(args.png)
    if args.val is not None:
        val_config = variant_config(args.run, [f"scene.source={args.val}"])
        val_scene = load_scene_for(val_config)
        model = load_ply(args.run / "model_stage1.ply")
        unseen = _unseen(model, [val_scene.cameras[c] for c in val_scene.train_ids])
        frames = list(range(0, val_scene.num_frames, val_config.eval.stride))
        cams = list(val_scene.test_ids)
        result["held_out"] = {"source": args.val, "cameras": cams, **_census(model, unseen),
                              "psnr": _psnr(model, val_scene, cams, frames, backend, background),
                              "psnr_without_unseen": _psnr(_without(model, unseen), val_scene, cams, frames,
                                                           backend, background)}
        h = result["held_out"]
        print(f"held-out cameras of {args.val}: {h['unseen']} unseen; {h['psnr']:.2f} dB, "
              f"{h['psnr_without_unseen']:.2f} without them")
    if args.out is not None:
        args.out.write_text(json.dumps(result, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
