"""Quality of initial clouds and depth maps against ground truth.

- True surface of a frame: points back-projected (Eq. 1) from the ground-truth z-depth of every
  camera (train and held-out) at that frame, randomly subsampled to a bounded count.
- accuracy: median distance from the cloud's points to their nearest true-surface sample
  (world units; also relative to the scene scale, the median ground-truth depth).
- completeness: share of true-surface samples with a cloud point within
  QUALITY_COMPLETENESS_REL x scene scale (1% of the viewing distance).
- depth errors of a depth map on its valid pixels that see a surface: abs-rel, shares within
  1% and 5%; valid_share = valid pixels / pixels that see a surface; coverage = pixels with a
  valid depth within 5% / pixels that see a surface (valid and right).

The ``frame_*`` helpers and ``summarize_clouds`` apply these to a scene with ground truth (a
synthetic scene: ``scene.depth``), the quality section of ``init_report.json``.
"""
from __future__ import annotations

from typing import Sequence

import numpy as np

from fixer4d.geometry.camera import Camera
import fixer4d.init.constants as C


def surface_samples(depths: Sequence[np.ndarray], cameras: Sequence[Camera], *,
                    max_samples: int = C.QUALITY_MAX_SURFACE_SAMPLES, seed: int = 0) -> tuple[np.ndarray, float]:
    """True-surface samples from ground-truth depth maps -> (points (M, 3), scene scale = median
    finite ground-truth depth)."""
    pts, zs = [], []
    for d, cam in zip(depths, cameras):
        d = np.asarray(d, np.float64)
        ok = np.isfinite(d) & (d > 0)
        if not ok.any():
            continue
        pts.append(cam.backproject_depth(np.where(ok, d, 0.0))[ok])
        zs.append(d[ok])
    if not pts:
        return np.zeros((0, 3)), float("nan")
    points = np.concatenate(pts)
    scale = float(np.median(np.concatenate(zs)))
    if points.shape[0] > max_samples:
        idx = np.random.default_rng(seed).choice(points.shape[0], max_samples, replace=False)
        points = points[idx]
    return points, scale


def cloud_quality(points: np.ndarray, surface: np.ndarray, scale: float,
                  tolerance_rel: float = C.QUALITY_COMPLETENESS_REL) -> dict:
    """accuracy (median cloud->surface distance), accuracy_rel (/ scale), completeness (share of
    surface samples within tolerance_rel x scale of the cloud) and the tolerance used."""
    from scipy.spatial import cKDTree

    points = np.asarray(points, np.float64).reshape(-1, 3)
    tol = tolerance_rel * scale
    out = {"accuracy": None, "accuracy_rel": None, "completeness": 0.0, "tolerance": tol, "points": int(points.shape[0])}
    if points.shape[0] == 0 or surface.shape[0] == 0:
        return out
    d_cloud, _ = cKDTree(surface).query(points, workers=-1)
    d_surf, _ = cKDTree(points).query(surface, distance_upper_bound=tol, workers=-1)
    acc = float(np.median(d_cloud))
    out.update(accuracy=acc, accuracy_rel=acc / scale, completeness=float(np.mean(d_surf <= tol)),
               accuracy_mean=float(np.mean(d_cloud)))
    return out


def depth_quality(pred: np.ndarray, valid: np.ndarray, gt: np.ndarray) -> dict:
    """Depth-map errors on one view (shapes (H, W), gt inf/NaN/0 where no surface)."""
    pred = np.asarray(pred, np.float64)
    gt = np.asarray(gt, np.float64)
    surf = np.isfinite(gt) & (gt > 0)
    v = np.asarray(valid, bool) & surf & np.isfinite(pred) & (pred > 0)
    n_surf = int(surf.sum())
    rel = np.abs(pred[v] - gt[v]) / gt[v]
    lo, hi = C.QUALITY_DEPTH_BANDS
    return {"pixels": n_surf, "valid": int(v.sum()),
            "abs_rel_sum": float(rel.sum()), "within_1pct": int((rel < lo).sum()), "within_5pct": int((rel < hi).sum())}


def summarize_depth(stats: Sequence[dict]) -> dict:
    """Pool per-view ``depth_quality`` counts into one summary (pixel-weighted)."""
    pixels = sum(s["pixels"] for s in stats)
    valid = sum(s["valid"] for s in stats)
    if pixels == 0:
        return {"depth_abs_rel": None, "depth_within_1pct": None, "depth_within_5pct": None,
                "valid_share": None, "coverage": None}
    return {"depth_abs_rel": sum(s["abs_rel_sum"] for s in stats) / valid if valid else None,
            "depth_within_1pct": sum(s["within_1pct"] for s in stats) / valid if valid else None,
            "depth_within_5pct": sum(s["within_5pct"] for s in stats) / valid if valid else None,
            "valid_share": valid / pixels,
            "coverage": sum(s["within_5pct"] for s in stats) / pixels}


def summarize_clouds(per_frame: Sequence[dict]) -> dict:
    """Pool per-frame ``cloud_quality`` results: mean accuracy and accuracy_rel (None when no
    frame has a point), mean completeness, the completeness tolerance (relative to the scene
    scale) and depth_abs_rel None, for a depth summary (``summarize_depth``) to fill in."""
    acc = [p["accuracy"] for p in per_frame if p.get("accuracy") is not None]
    return {"accuracy": float(np.mean(acc)) if acc else None,
            "accuracy_rel": float(np.mean([p["accuracy_rel"] for p in per_frame if p.get("accuracy_rel") is not None]))
            if acc else None,
            "completeness": float(np.mean([p["completeness"] for p in per_frame])),
            "completeness_tolerance_rel": C.QUALITY_COMPLETENESS_REL,
            "depth_abs_rel": None}


def frame_cloud_quality(scene, frame: int, points: np.ndarray) -> dict:
    """``cloud_quality`` of one frame's cloud (N, 3) against the true surface of every camera of
    ``scene`` (train, then held-out) at ``frame``."""
    ids = list(scene.train_ids) + [i for i in scene.test_ids if i not in scene.train_ids]
    surface, scale = surface_samples([scene.depth(frame, i) for i in ids], [scene.cameras[i] for i in ids])
    return cloud_quality(points, surface, scale)


def frame_depth_quality(scene, frame: int, results: Sequence, excluded: Sequence[np.ndarray] | None = None
                        ) -> list[dict]:
    """``depth_quality`` of each train view's DepthResult at ``frame`` against the scene's true
    depth at the result's resolution. excluded: optional per view (H, W) bool at the result's
    resolution, pixels left out of both the prediction and the truth."""
    stats = []
    for v, (r, i) in enumerate(zip(results, scene.train_ids)):
        if excluded is None:
            stats.append(depth_quality(r.depth, r.valid, gt_depth_at(scene, i, frame, r.camera)))
        else:
            stats.append(depth_quality(r.depth, r.valid & ~excluded[v],
                                       np.where(excluded[v], np.nan, gt_depth_at(scene, i, frame, r.camera))))
    return stats


def gt_depth_at(scene, cam_index: int, frame: int, camera: Camera) -> np.ndarray:
    """Ground-truth depth of scene camera ``cam_index`` at ``camera``'s resolution."""
    full = scene.cameras[cam_index]
    if (camera.width, camera.height) == (full.width, full.height):
        return scene.depth(frame, cam_index)
    if hasattr(scene, "render_gt"):
        return scene.render_gt(full.resized(camera.width, camera.height), scene.time(frame))[1]
    import cv2

    return cv2.resize(scene.depth(frame, cam_index), (camera.width, camera.height), interpolation=cv2.INTER_NEAREST)
