"""Level of detail for moving frames: which splats to draw when only a fraction fits the budget.

On a software GL (Mesa llvmpipe) a splat frame at reduced resolution costs about 3 us per splat
(triangle setup and binning run on one thread: on the demo's 30k-splat surfaces at 196x108,
30k -> 180 ms, 8k -> 60 ms, 4k -> 19 ms, load ~4), so while the camera moves the view draws the
most important splats and the full set once it rests (playback with a resting camera always
draws every splat: ``app.frame_cache``).

Importance is what a splat contributes on screen for this view: its projected area (the
largest world std over its depth, times the focal length, squared) times its opacity at the
current time. The subset is the ``count`` most important splats, kept in depth order; it is
computed with the depth order on the sorter thread, so a moving frame pays nothing for it. No
random sampling: the same view always draws the same splats, and a large near splat is never
dropped for a faint far one.

The kept splats stand in for the dropped ones: their 2D covariance is scaled so the total
screen area of the kept set equals that of the whole set (``area_factor``), capped at n / count.
"""
from __future__ import annotations

import numpy as np

# Smallest depth (scene units) used to size a splat on screen: a splat at the near plane would
# otherwise get an unbounded area.
_Z_MIN = 1e-3


def screen_importance(means_cam_z: np.ndarray, log_scales: np.ndarray, opacity: np.ndarray,
                      focal: float) -> tuple[np.ndarray, np.ndarray]:
    """(area, importance), each (N,) float32: the projected area of each splat in px^2 (largest
    std (N,3) ``exp(log_scales)`` at camera depth ``means_cam_z`` (N,) with ``focal`` px) and area
    x ``opacity`` (N,) at the current time."""
    size = np.exp(np.max(np.asarray(log_scales, np.float32), axis=1)) * np.float32(focal)
    area = (size / np.maximum(np.asarray(means_cam_z, np.float32), _Z_MIN)) ** 2
    return area.astype(np.float32), (area * np.asarray(opacity, np.float32)).astype(np.float32)


def lod_count(n: int, fraction: float) -> int:
    """Splats drawn of ``n`` at ``fraction`` (at least 1 when n > 0)."""
    if n <= 0:
        return 0
    return int(min(n, max(1, int(np.ceil(float(fraction) * n)))))


def lod_subset(order: np.ndarray, importance: np.ndarray, count: int) -> np.ndarray:
    """The ``count`` entries of a depth ``order`` (indices, front to back) with the highest
    ``importance`` (indexed like the Gaussians), still front to back; ties broken by depth."""
    order = np.asarray(order)
    if count >= order.size:
        return order
    if count <= 0:
        return order[:0]
    imp = np.asarray(importance)[order]
    keep = np.argpartition(-imp, count - 1)[:count]
    keep.sort()  # positions in the depth order: front to back
    return order[keep]


def area_factor(area_all: float, area_kept: float, n: int, count: int) -> float:
    """Scale of each kept splat's 2D covariance: the whole set's screen area over the kept
    set's (1 when all are drawn), at most n / count."""
    if count <= 0 or count >= n or area_kept <= 0.0:
        return 1.0
    return float(np.clip(area_all / area_kept, 1.0, float(n) / float(count)))
