"""Image-space debug maps that need more than the GL resolve pass: the blur map.

Blur = detail the nearest real reference has and the render lacks. The reference frame is
warped into the view through the render's depth (back-project each pixel, project into the
reference, sample), then detail = local mean of |Laplacian| of the luminance on both; the map
is max(detail(warped reference) - detail(render), 0) where the warp lands inside the
reference, 0 elsewhere. Occlusions are not tested (a debugging aid, not a metric).
"""
from __future__ import annotations

import cv2
import numpy as np

from fixer4d.geometry.camera import Camera

# Side of the box filter that averages |Laplacian| into a local detail measure (pixels): about
# the size of the blur a splat of a few pixels causes.
DETAIL_WINDOW = 7
# Pixels with less accumulated alpha than this have no reliable depth to warp through.
MIN_WARP_ALPHA = 0.5
LUMA = np.array([0.299, 0.587, 0.114], np.float32)


def detail(image: np.ndarray) -> np.ndarray:
    """(H, W) local mean |Laplacian| of the luminance of an (H, W, 3) float image."""
    y = (np.asarray(image, np.float32) @ LUMA).astype(np.float32)
    lap = np.abs(cv2.Laplacian(y, cv2.CV_32F, ksize=3))
    return cv2.blur(lap, (DETAIL_WINDOW, DETAIL_WINDOW))


def warp_reference(ref_image: np.ndarray, ref_cam: Camera, cam: Camera, depth: np.ndarray,
                   alpha: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Warp ``ref_image`` (seen by ``ref_cam``) into ``cam`` through ``depth`` (H, W) z-depth.
    Returns (warped (H, W, 3), valid (H, W) bool)."""
    H, W = depth.shape
    pts = cam.backproject_depth(np.where(alpha >= MIN_WARP_ALPHA, depth, 1.0)).reshape(-1, 3)
    uv, z = ref_cam.project(pts)
    uv = uv.reshape(H, W, 2)
    rh, rw = ref_image.shape[:2]
    with np.errstate(invalid="ignore"):
        valid = (alpha >= MIN_WARP_ALPHA) & (z.reshape(H, W) > 0) & np.all(np.isfinite(uv), -1) \
            & (uv[..., 0] >= 0) & (uv[..., 0] < rw) & (uv[..., 1] >= 0) & (uv[..., 1] < rh)
    # K-projection coordinate u maps to array index u - 0.5 (pixel centres at +0.5)
    map_xy = np.where(valid[..., None], uv - 0.5, -1.0).astype(np.float32)
    warped = cv2.remap(np.asarray(ref_image, np.float32), map_xy[..., 0], map_xy[..., 1], cv2.INTER_LINEAR,
                       borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    return warped, valid


def blur_map(render_rgb: np.ndarray, depth: np.ndarray, alpha: np.ndarray, cam: Camera,
             ref_image: np.ndarray, ref_cam: Camera) -> np.ndarray:
    """(H, W) float32 missing detail of the render against the warped reference (0 = none)."""
    warped, valid = warp_reference(ref_image, ref_cam, cam, depth, alpha)
    return np.where(valid, np.maximum(detail(warped) - detail(render_rgb), 0.0), 0.0).astype(np.float32)


def nearest_camera(cameras: list[Camera], cam: Camera) -> int:
    """Index of the camera closest to ``cam`` (centre distance plus viewing-angle difference
    in units of the rig size)."""
    scale = max(np.ptp(np.stack([c.center for c in cameras]), axis=0).max(), 1e-9)
    cost = [np.linalg.norm(c.center - cam.center) / scale + (1.0 - float(c.forward @ cam.forward)) for c in cameras]
    return int(np.argmin(cost))
