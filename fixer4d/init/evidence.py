"""Colour evidence from the static points the train views share (fixer4d.model.terms decides
from it): per point, how much its colour changes across the views that see it with each camera's
exposure removed (the SH degree); per view, that exposure itself (the camera response,
fixer4d.model.camera_response.view_gains)."""
from __future__ import annotations

from typing import Sequence

import numpy as np

from fixer4d.init.view_sampling import bilinear, resize_mask, visible_in

# Blur (pixels) of the median images before the static points' colours are compared across
# views: sub-pixel misregistration of fine texture otherwise looks like view dependence (on the
# matte demo room, 4.3% of the points differ by > 0.06 unblurred, 0.9% after a 2 px blur,
# while a highlight, smooth over many pixels, survives it).
EVIDENCE_BLUR_SIGMA = 2.0


def sample_view_colors(points: np.ndarray, images: Sequence[np.ndarray], results,
                       moving_any: Sequence[np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The colour each train view records for each static point: (colors (V, N, 3) float64, zero
    where not visible; visible (V, N) bool).

    images: V median images (any size; resized to each result's resolution), blurred by
    EVIDENCE_BLUR_SIGMA; results: the V static DepthResults (visibility). moving_any: optional V
    (H, W) bool at the images' resolution, pixels that move in some frame (their median colour
    mixes in moving content; they are left out).
    """
    import cv2

    V, N = len(results), points.shape[0]
    cols = np.zeros((V, N, 3))
    vis = np.zeros((V, N), bool)
    for v, r in enumerate(results):
        img = cv2.GaussianBlur(np.asarray(images[v], np.float32), (0, 0), EVIDENCE_BLUR_SIGMA)
        if img.shape[:2] != r.depth.shape:
            img = cv2.resize(img, (r.depth.shape[1], r.depth.shape[0]), interpolation=cv2.INTER_AREA)
        valid = r.valid if moving_any is None else r.valid & ~resize_mask(np.asarray(moving_any[v]), r.depth.shape)
        vis[v], uv = visible_in(points, r.depth, valid, r.camera)
        cols[v, vis[v]] = bilinear(img, uv[vis[v]])
    return cols, vis


def color_spread(colors: np.ndarray, visible: np.ndarray) -> np.ndarray:
    """Exposure-corrected colour std (N,) float32 of points across the views that see them.

    colors (V, N, 3), visible (V, N) as ``sample_view_colors`` returns them. Each view's colour
    offset from the across-view mean is removed first (its median over the points it sees), so a
    camera's exposure or white balance is not counted as view dependence. NaN where fewer than 2
    views see the point.
    """
    cols, vis = np.array(colors, np.float64), np.asarray(visible, bool)
    V = cols.shape[0]
    n = vis.sum(0)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = (cols * vis[..., None]).sum(0) / n[:, None]
        for v in range(V):
            m = vis[v] & (n >= 2)
            if m.any():
                cols[v] -= np.median(cols[v, m] - mean[m], axis=0)
        mean = (cols * vis[..., None]).sum(0) / n[:, None]
        var = (((cols - mean[None]) ** 2) * vis[..., None]).sum(0) / n[:, None]
    std = np.sqrt(var.mean(1))
    std[n < 2] = np.nan
    return std.astype(np.float32)

