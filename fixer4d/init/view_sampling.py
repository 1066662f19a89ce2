"""Where points land in a view: visibility against the view's depth map, bilinear samples of an
image-like field at continuous pixel coordinates, and masks resized to a depth map's grid."""
from __future__ import annotations

import numpy as np

from fixer4d.geometry.camera import Camera

# Relative depth agreement for "the point is visible in this view" (same as the fusion test's
# order of magnitude, a little looser because crops are swept with fewer planes' support).
VISIBILITY_DEPTH_TOL = 0.02


def resize_mask(mask: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """(H, W) bool ``mask`` at ``shape`` (nearest neighbour; unchanged when it has that shape)."""
    if mask.shape == shape:
        return mask
    import cv2

    return cv2.resize(mask.astype(np.uint8), (shape[1], shape[0]), interpolation=cv2.INTER_NEAREST) > 0


def visible_in(points: np.ndarray, depth: np.ndarray, valid: np.ndarray, cam: Camera,
               tol: float = VISIBILITY_DEPTH_TOL) -> tuple[np.ndarray, np.ndarray]:
    """Which points (N,3) a depth map of ``cam`` sees: (visible (N,) bool, uv (N,2) pixels)."""
    uv, z = cam.project(points)
    with np.errstate(invalid="ignore"):
        iu, iv = np.floor(uv[:, 0]), np.floor(uv[:, 1])
        inside = (z > 0) & (iu >= 0) & (iu < cam.width) & (iv >= 0) & (iv < cam.height)
    d = np.zeros(points.shape[0])
    ok = np.zeros(points.shape[0], bool)
    ii, jj = iv[inside].astype(np.int64), iu[inside].astype(np.int64)
    d[inside] = depth[ii, jj]
    ok[inside] = valid[ii, jj]
    with np.errstate(invalid="ignore", divide="ignore"):
        vis = inside & ok & (d > 0) & (np.abs(z - d) <= tol * np.maximum(d, 1e-12))
    return vis, uv


def bilinear(field2: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Sample an (H, W, C) field at continuous pixel coordinates uv (N, 2) (pixel centres at +0.5)."""
    h, w = field2.shape[:2]
    x = np.clip(uv[:, 0] - 0.5, 0, w - 1.001)
    y = np.clip(uv[:, 1] - 0.5, 0, h - 1.001)
    x0, y0 = np.floor(x).astype(np.int64), np.floor(y).astype(np.int64)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    return ((1 - fx) * (1 - fy) * field2[y0, x0] + fx * (1 - fy) * field2[y0, x0 + 1]
            + (1 - fx) * fy * field2[y0 + 1, x0] + fx * fy * field2[y0 + 1, x0 + 1])
