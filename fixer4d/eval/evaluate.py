"""The evaluation protocol: render every held-out camera at every (or every S-th) frame and score it.

``evaluate(render_fn, scene, out_dir, ...)`` writes into ``out_dir``:

- ``metrics.json``: ``{"method", "mean": {psnr, dssim1, dssim2, lpips|null}, "per_view": {camera:
  {...}}, "seconds": {"prep", "train", "eval"}, "lpips_unavailable_reason": str|null}`` (the
  metrics.json contract) plus ``per_frame`` (one entry per rendered image), ``protocol`` (frames,
  cameras, resolution, metric settings), ``timing`` and ``examples``;
- ``metrics.md``: the paper's table layout (Method | PSNR | DSSIM1 | DSSIM2 | LPIPS | Prep. time),
  plus PSNR over the moving / static pixels;
- ``example_<camera>_f<frame>.png``: render | ground truth | error heatmap, for a few frames.

Every file is written atomically. Renders are clamped to [0, 1] before scoring (as STGS's test
script does); PSNR is computed per image and averaged.

Dynamic-region metrics: every per-frame row, ``per_view`` and ``mean`` also hold
``psnr_dynamic`` / ``psnr_static`` (10 log10(1 / MSE) over the held-out image's moving / static
pixels) and ``ssim_dynamic`` / ``ssim_static`` (mean of the SSIM map, data range 1, over them),
plus ``moving_fraction``. The moving mask of a held-out image is
- exact on synthetic scenes: ``scene.moving_mask(frame, camera)`` (ray-caster: the pixel's first
  hit is a moving object);
- on real scenes, estimated from the held-out video itself by the init's estimator
  (``fixer4d.init.masks.moving_masks_for_scene``: per-pixel temporal median of that camera's
  clip, noise-relative threshold, cleanup; scene segmentation where the layout has one for it).
The mask only selects pixels to score; it never feeds training. A region with no pixels in an
image scores None there; means are over the images where the region is not empty (None when
there is none). ``protocol.regions`` records which mask was used.

Unobserved pixels: given ``unobserved_fn(camera_index, frame) -> (H, W) bool``, every row also
holds ``psnr_unobserved`` (PSNR over the pixels no train camera explains; the run passes the mask
of ``restore.visibility`` computed from the stage-1 model's renders at the held-out camera and the
train cameras: no held-out image is read) and ``unobserved_fraction``.

Exposure-aligned PSNR: ``psnr_aligned`` is the PSNR after a per-image, per-channel affine fit of
the render to the ground truth (least squares, ``metrics.exposure_aligned``), the "colour-corrected"
convention of in-the-wild view synthesis: it shows how much of the error is camera exposure and
white balance rather than geometry. The raw PSNR stays the headline.
"""
from __future__ import annotations

import math
import re
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from fixer4d.atomic import atomic_path, write_json, write_text
from fixer4d.errors import InputError, NumericalError
from fixer4d.eval import metrics as M
from fixer4d.geometry.camera import Camera
from fixer4d.threads import digit_threads

METRIC_KEYS = ("psnr", "dssim1", "dssim2", "lpips")
# Scores over the held-out image's moving / static pixels (None where the region is empty).
REGION_KEYS = ("psnr_dynamic", "psnr_static", "ssim_dynamic", "ssim_static")
# Scores present only when their input is (an unobserved-pixel mask): None otherwise.
OPTIONAL_KEYS = ("psnr_unobserved",)
ALIGNED_KEYS = ("psnr_aligned",)
REGION_MASK_EXACT = "exact: ray-caster moving-object mask (synthetic ground truth)"
REGION_MASK_ESTIMATED = "estimated: temporal statistics of the held-out video (fixer4d.init.masks)"
# Absolute error (per pixel, mean over RGB) that maps to the top of the heatmap's colour scale.
# Fixed rather than per-image so heatmaps of different frames and methods are comparable; 0.25
# keeps typical reconstruction errors (0.02-0.2) in the visible range.
ERROR_VIS_MAX = 0.25
ERROR_COLORMAP = "inferno"


def select_frames(num_frames: int, frame_stride: int = 1, frames: Sequence[int] | None = None) -> list[int]:
    """The frames the protocol evaluates: ``(frames or range(num_frames))[::frame_stride]``."""
    if int(frame_stride) < 1:
        raise InputError(f"frame_stride must be >= 1, got {frame_stride}")
    base = list(range(num_frames)) if frames is None else [int(f) for f in frames]
    bad = [f for f in base if not 0 <= f < num_frames]
    if bad:
        raise InputError(f"frames {bad[:5]} are outside the scene's [0, {num_frames}) frame range")
    chosen = base[::int(frame_stride)]
    if not chosen:
        raise InputError("no frames to evaluate (empty frame list)")
    return chosen


def _view_keys(scene, test_ids: Sequence[int]) -> list[str]:
    """A unique, readable key per held-out camera (its name, else its index)."""
    keys: list[str] = []
    for i in test_ids:
        name = scene.cameras[i].name or f"cam{i}"
        keys.append(name if name not in keys else f"{name}#{i}")
    return keys


def _finite_or_none(x: float | None) -> float | None:
    """JSON has no inf/NaN: an exact render (PSNR = inf) is written as null."""
    return None if x is None or not math.isfinite(x) else float(x)


def _mean(values: list[float | None]) -> float | None:
    """Mean of the values, or None when any is None (LPIPS unavailable)."""
    if not values or any(v is None for v in values):
        return None
    return float(np.mean(values))


def _mean_present(values: list[float | None]) -> float | None:
    """Mean of the finite values that are not None (regions empty in some images), or None."""
    kept = [v for v in values if v is not None and math.isfinite(v)]
    return float(np.mean(kept)) if kept else None


def heldout_moving_masks(scene, cam_idx: int, frames: Sequence[int]) -> tuple[np.ndarray, str]:
    """Moving-content masks (F, H, W) bool of held-out camera ``cam_idx`` at ``frames`` and the
    rule used (REGION_MASK_EXACT or REGION_MASK_ESTIMATED; see the module docstring)."""
    exact = getattr(scene, "moving_mask", None)
    if callable(exact):
        return np.stack([np.asarray(exact(f, cam_idx), bool) for f in frames]), REGION_MASK_EXACT
    from fixer4d.init.masks import moving_masks_for_scene

    return moving_masks_for_scene(scene, [cam_idx], frames)[0], REGION_MASK_ESTIMATED


def _slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]+", "_", text).strip("_") or "view"


def error_heatmap(pred: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """(H, W, 3) float32 RGB heatmap of the per-pixel mean absolute error, 0..ERROR_VIS_MAX."""
    from matplotlib import colormaps

    err = np.abs(pred.astype(np.float32) - gt.astype(np.float32)).mean(axis=-1)
    return colormaps[ERROR_COLORMAP](np.clip(err / ERROR_VIS_MAX, 0.0, 1.0))[..., :3].astype(np.float32)


def side_by_side(pred: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """(H, 3W, 3) uint8: render | ground truth | error heatmap."""
    row = np.concatenate([pred, gt, error_heatmap(pred, gt)], axis=1)
    return (np.clip(row, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def _save_png(path: Path, image_u8: np.ndarray) -> None:
    from PIL import Image

    with atomic_path(path) as tmp:
        Image.fromarray(image_u8).save(tmp, format="PNG")


def _format_seconds(s: float | None) -> str:
    if s is None:
        return "n/a"
    if s < 60:
        return f"{s:.1f} s"
    if s < 3600:
        return f"{s / 60:.1f} min"
    return f"{s / 3600:.2f} h"


def _format(value: float | None, digits: int) -> str:
    return "n/a" if value is None else f"{value:.{digits}f}"


def markdown_table(rows: Sequence[dict[str, Any]]) -> str:
    """The paper's table layout for evaluation results.

    rows: dicts shaped like metrics.json (``method``, ``mean``, ``seconds``), e.g. the return
    values of :func:`evaluate` or loaded metrics.json files. Returns markdown text, header
    included, one line per row: Method | PSNR | DSSIM1 | DSSIM2 | LPIPS | Prep. time.
    A missing value (LPIPS unavailable, exact render, unknown preparation time) reads "n/a".
    """
    regions = any("psnr_dynamic" in row.get("mean", {}) for row in rows)
    extra_head, extra_rule = (" PSNR dyn. ↑ | PSNR static ↑ |", "---:|---:|") if regions else ("", "")
    lines = [f"| Method | PSNR ↑ | DSSIM1 ↓ | DSSIM2 ↓ | LPIPS ↓ |{extra_head} Prep. time |",
             f"|---|---:|---:|---:|---:|{extra_rule}---:|"]
    for row in rows:
        mean = row.get("mean", {})
        prep = row.get("seconds", {}).get("prep")
        extra = (f" {_format(mean.get('psnr_dynamic'), 2)} | {_format(mean.get('psnr_static'), 2)} |"
                 if regions else "")
        lines.append(f"| {row.get('method', '?')} | {_format(mean.get('psnr'), 2)} | "
                     f"{_format(mean.get('dssim1'), 4)} | {_format(mean.get('dssim2'), 4)} | "
                     f"{_format(mean.get('lpips'), 4)} |{extra} {_format_seconds(prep)} |")
    return "\n".join(lines) + "\n"


@digit_threads()  # LPIPS's digits, like a run's, do not follow the core count
def evaluate(render_fn: Callable[[Camera, float], np.ndarray], scene, out_dir: str | Path, *,
             frame_stride: int = 1, frames: Sequence[int] | None = None, method_name: str = "fixer4d",
             seconds: dict[str, float] | None = None, save_examples: int = 3,
             progress: bool = True,
             unobserved_fn: Callable[[int, int], np.ndarray] | None = None) -> dict[str, Any]:
    """Score ``render_fn`` on every held-out camera of ``scene`` and write the results to ``out_dir``.

    render_fn(camera, t) -> (H, W, 3) float32 RGB for the camera at clip time t = f / T.
    scene: a MultiViewVideo (its ``test_ids`` are the held-out cameras; ``frame(f, cam)`` the
    ground truth). frames / frame_stride: see :func:`select_frames`. seconds: the run's
    ``{"prep": s, "train": s}`` (unknown ones are written as null); ``eval`` is measured here.
    save_examples: frames (evenly spaced among those evaluated) saved as PNGs per view.
    unobserved_fn(camera_index, frame) -> (H, W) bool: the pixels no train camera explains
    (scored as ``psnr_unobserved``; None: not scored).
    A scene without held-out cameras is scored on its train cameras (the fit, not novel views;
    ``held_out`` False in the result). Returns the metrics.json content. Raises InputError for a
    render of the wrong shape, NumericalError for a non-finite render.

    A run sets these from its ``eval`` section (``fixer4d.pipeline.config.EvalConfig``: stride
    -> frame_stride, examples -> save_examples); metrics.json's ``protocol`` records them.
    """
    t_start = time.perf_counter()
    out_dir = Path(out_dir)
    test_ids = [int(i) for i in scene.test_ids]
    held_out = bool(test_ids)
    if not held_out:  # a capture that trains on every camera: score the fit to the train views
        test_ids = [int(i) for i in scene.train_ids]
    if not test_ids:
        raise InputError(f"scene {scene.name!r} has no cameras to evaluate (no train or held-out cameras)")
    chosen = select_frames(scene.num_frames, frame_stride, frames)
    keys = _view_keys(scene, test_ids)
    n_examples = max(0, min(int(save_examples), len(chosen)))
    example_frames = ({chosen[int(round(k))] for k in np.linspace(0, len(chosen) - 1, n_examples)}
                      if n_examples else set())
    scores = _score_images(render_fn, scene, out_dir, test_ids, keys, chosen, example_frames, method_name,
                           progress, unobserved_fn)
    per_view, mean = _summaries(scores.per_frame, test_ids, keys, unobserved_fn is not None)
    seconds = dict(seconds or {})
    result: dict[str, Any] = {
        "method": method_name,
        "held_out": held_out,
        "mean": mean,
        "per_view": per_view,
        "seconds": {"prep": _finite_or_none(seconds.get("prep")), "train": _finite_or_none(seconds.get("train")),
                    "eval": None},
        "lpips_unavailable_reason": _lpips_reason(scene),
        "per_frame": scores.per_frame,
        "protocol": _protocol(scene, test_ids, keys, chosen, frame_stride, scores, unobserved_fn is not None),
        "timing": {"render_seconds": scores.render_s, "metrics_seconds": scores.metric_s,
                   "mask_seconds": scores.mask_s},
        "examples": scores.examples,
    }
    result["seconds"]["eval"] = time.perf_counter() - t_start
    write_json(out_dir / "metrics.json", result)
    write_text(out_dir / "metrics.md", markdown_table([result]))
    return result


@dataclass
class _Scores:
    """What scoring every image gave: per-frame rows, example files, the region-mask rules used
    and the seconds spent rendering, scoring and computing masks."""

    per_frame: list[dict[str, Any]] = field(default_factory=list)
    examples: list[str] = field(default_factory=list)
    mask_rules: set[str] = field(default_factory=set)
    render_s: float = 0.0
    metric_s: float = 0.0
    mask_s: float = 0.0


def _score_images(render_fn: Callable[[Camera, float], np.ndarray], scene, out_dir: Path, test_ids: list[int],
                  keys: list[str], chosen: list[int], example_frames: set[int], method_name: str, progress: bool,
                  unobserved_fn: Callable[[int, int], np.ndarray] | None) -> _Scores:
    """Render and score every (camera, frame) pair, saving the example PNGs on the way."""
    from tqdm.auto import tqdm

    sc = _Scores()
    bar = tqdm(total=len(chosen) * len(test_ids), desc=f"eval {method_name}", unit="img", disable=not progress)
    for cam_idx, key in zip(test_ids, keys):
        camera = scene.cameras[cam_idx]
        t0 = time.perf_counter()
        moving, rule = heldout_moving_masks(scene, cam_idx, chosen)
        sc.mask_s += time.perf_counter() - t0
        sc.mask_rules.add(rule)
        for j, f in enumerate(chosen):
            t = scene.time(f)
            t0 = time.perf_counter()
            pred = np.asarray(render_fn(camera, t))
            sc.render_s += time.perf_counter() - t0
            gt = np.asarray(scene.frame(f, cam_idx), dtype=np.float32)
            pred = _checked_render(pred, gt, key, f)
            t0 = time.perf_counter()
            m, extra = _image_scores(pred, gt, moving[j], cam_idx, f, unobserved_fn)
            sc.metric_s += time.perf_counter() - t0
            sc.per_frame.append({"camera": key, "camera_index": cam_idx, "frame": f, "time": t, **m,
                                 "moving_fraction": float(moving[j].mean()), **extra})
            if f in example_frames:
                name = f"example_{_slug(key)}_f{f:04d}.png"
                _save_png(out_dir / name, side_by_side(pred, gt))
                sc.examples.append(name)
            bar.update(1)
            bar.set_postfix(psnr=f"{m['psnr']:.2f}")
    bar.close()
    return sc


def _checked_render(pred: np.ndarray, gt: np.ndarray, key: str, f: int) -> np.ndarray:
    """The render (H, W, 3) clamped to [0, 1] in float32; InputError for a shape other than the
    ground truth's, NumericalError for NaN/inf."""
    if pred.shape != gt.shape:
        raise InputError(f"render of camera {key} at frame {f} has shape {pred.shape}, but the ground truth "
                         f"is {gt.shape}; render at the scene camera's resolution")
    if not np.isfinite(pred).all():
        raise NumericalError(f"render of camera {key} at frame {f} contains NaN/inf; the model is corrupt")
    return np.clip(pred.astype(np.float32), 0.0, 1.0)


def _image_scores(pred: np.ndarray, gt: np.ndarray, moving: np.ndarray, cam_idx: int, f: int,
                  unobserved_fn: Callable[[int, int], np.ndarray] | None) -> tuple[dict[str, Any], dict[str, Any]]:
    """(scores, extra fields) of one image: the image and region metrics, the exposure-aligned
    PSNR and, given ``unobserved_fn``, the PSNR over the unobserved pixels and their share."""
    m = M.image_metrics(pred, gt)
    m.update(M.region_metrics(pred, gt, moving))
    m["psnr_aligned"] = M.psnr(M.exposure_aligned(pred, gt), gt)
    extra: dict[str, Any] = {}
    if unobserved_fn is not None:
        hidden = np.asarray(unobserved_fn(cam_idx, f), bool)
        m["psnr_unobserved"] = M.masked_psnr(pred, gt, hidden)
        extra["unobserved_fraction"] = float(hidden.mean())
    return m, extra


def _summaries(per_frame: list[dict[str, Any]], test_ids: list[int], keys: list[str],
               unobserved: bool) -> tuple[dict[str, dict[str, Any]], dict[str, Any]]:
    """(per_view, mean) over the per-frame rows; then every row's scores are made JSON-safe
    (inf/NaN -> None) in place."""
    scored = METRIC_KEYS + ALIGNED_KEYS
    present = REGION_KEYS + (OPTIONAL_KEYS if unobserved else ())
    per_view: dict[str, dict[str, Any]] = {}
    for cam_idx, key in zip(test_ids, keys):
        rows = [r for r in per_frame if r["camera_index"] == cam_idx]
        per_view[key] = {"camera_index": cam_idx, "frames": len(rows),
                         **{k: _finite_or_none(_mean([r[k] for r in rows])) for k in scored},
                         **{k: _mean_present([r[k] for r in rows]) for k in present},
                         "moving_fraction": float(np.mean([r["moving_fraction"] for r in rows]))}
        if unobserved:
            per_view[key]["unobserved_fraction"] = float(np.mean([r["unobserved_fraction"] for r in rows]))
    mean = {k: _finite_or_none(_mean([r[k] for r in per_frame])) for k in scored}
    mean.update({k: _mean_present([r[k] for r in per_frame]) for k in present})
    if unobserved:
        mean["unobserved_fraction"] = float(np.mean([r["unobserved_fraction"] for r in per_frame]))
    for r in per_frame:
        for k in scored + present:
            r[k] = _finite_or_none(r[k])
    return per_view, mean


def _protocol(scene, test_ids: list[int], keys: list[str], chosen: list[int], frame_stride: int, scores: _Scores,
              unobserved: bool) -> dict[str, Any]:
    """metrics.json's ``protocol``: what was scored and how."""
    cam0 = scene.cameras[test_ids[0]]
    rules = scores.mask_rules
    return {
        "scene": scene.name,
        "test_cameras": keys,
        "frames": chosen,
        "frame_stride": int(frame_stride),
        "num_frames": scene.num_frames,
        "resolution": [cam0.width, cam0.height],
        "images": len(scores.per_frame),
        "render_clamped_to_01": True,
        "psnr": "per image, data range 1, averaged over images",
        "ssim": {"implementation": "skimage.metrics.structural_similarity", "win_size": M.SSIM_WIN_SIZE,
                 "gaussian_weights": False, "use_sample_covariance": True, "channel_axis": -1,
                 "dssim1_data_range": M.DSSIM1_DATA_RANGE, "dssim2_data_range": M.DSSIM2_DATA_RANGE},
        "lpips": {"net": "alex", "weights": M.lpips_weights_path()},
        "regions": {"mask": sorted(rules)[0] if len(rules) == 1 else sorted(rules),
                    "psnr": "10 log10(1 / MSE) over the region's pixels, per image; mean over images "
                            "where the region is not empty",
                    "ssim": "mean of the SSIM map (data range 1) over the region",
                    "moving_fraction": float(np.mean([r["moving_fraction"] for r in scores.per_frame])),
                    "unobserved": None if not unobserved else
                    "restore.visibility of the stage-1 model's renders (train cameras only), weight > 0.5"},
        "psnr_aligned": "PSNR after a per-image per-channel affine fit of the render to the ground truth",
    }


def _lpips_reason(scene) -> str | None:
    """Why LPIPS is missing from this evaluation, or None when it was computed."""
    from fixer4d.eval.lpips import MIN_SIDE

    reason = M.lpips_unavailable_reason()
    if reason is None and any(min(scene.cameras[i].width, scene.cameras[i].height) < MIN_SIDE for i in scene.test_ids):
        reason = f"held-out images smaller than {MIN_SIDE}x{MIN_SIDE} pixels (LPIPS-alex needs at least that)"
    return reason
