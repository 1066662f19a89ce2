"""What a multi-view depth estimator takes and returns: the DepthEstimator protocol, its
DepthResult, and the input check every estimator runs first (``check_views``)."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, Sequence, runtime_checkable

import numpy as np

from fixer4d.errors import InputError
from fixer4d.geometry.camera import Camera


@dataclass
class DepthResult:
    """Depth of one view at the estimator's working resolution.

    depth: (H, W) float32 z-depth (0 where invalid). valid: (H, W) bool. confidence: (H, W)
    float32 in [0, 1]. camera: the camera at that resolution (H, W may differ from the input
    image when the estimator works at a reduced scale).
    """

    depth: np.ndarray
    valid: np.ndarray
    confidence: np.ndarray
    camera: Camera


@runtime_checkable
class DepthEstimator(Protocol):
    """V synchronized images + cameras -> one DepthResult per view."""

    name: str

    def estimate(self, images: Sequence[np.ndarray], cameras: Sequence[Camera],
                 depth_ranges: Sequence[tuple[float, float]] | None = None) -> list[DepthResult]:
        """images: V (H, W, 3) float32 RGB in [0, 1]; cameras: V posed cameras; depth_ranges:
        optional per-view (near, far) z-depths."""
        ...


def check_views(images: Sequence[np.ndarray], cameras: Sequence[Camera]) -> int:
    """The number of views V, after checking one (H, W, 3) image per camera at the camera's
    size and at least 2 views (InputError naming the camera otherwise)."""
    if len(images) != len(cameras):
        raise InputError(f"{len(images)} images but {len(cameras)} cameras; pass one camera per image")
    if len(images) < 2:
        raise InputError(f"multi-view stereo needs at least 2 views, got {len(images)}")
    for img, cam in zip(images, cameras):
        shape = np.asarray(img).shape
        if len(shape) != 3 or shape[2] != 3:
            raise InputError(f"camera {cam.name!r}: image must be (H, W, 3) RGB, got shape {shape}")
        if shape[:2] != (cam.height, cam.width):
            raise InputError(f"camera {cam.name!r}: image is {shape[0]}x{shape[1]} but the camera is "
                             f"{cam.height}x{cam.width}; resize the image or use Camera.resized")
    return len(images)
