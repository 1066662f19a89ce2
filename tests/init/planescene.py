"""A fronto-parallel textured plane seen by 4 cameras with the same orientation: exact depth."""
from __future__ import annotations

import numpy as np

from fixer4d.geometry.camera import Camera
from toyscene import noise_texture

PLANE_Z = 4.0


def plane_cameras(width: int = 96, height: int = 72, baseline: float = 0.35) -> list[Camera]:
    K = Camera.intrinsics_from_fov(np.radians(50.0), width, height)
    offsets = [(-baseline, -baseline * 0.5), (baseline, -baseline * 0.5), (-baseline, baseline * 0.5),
               (baseline, baseline * 0.5)]
    cams = []
    for i, (x, y) in enumerate(offsets):
        c2w = np.eye(4)
        c2w[:3, 3] = [x, y, 0.0]
        cams.append(Camera(K, c2w, width, height, f"p{i}"))
    return cams


def render_plane(cam: Camera, textured: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """(H, W, 3) image and (H, W) z-depth of the plane z = PLANE_Z (cameras look along +z)."""
    d = cam.ray_directions()
    lam = (PLANE_Z - cam.center[2]) / d[..., 2]
    p = cam.center + lam[..., None] * d
    img = noise_texture(p[..., 0] * 0.5, p[..., 1] * 0.5) if textured else np.full(p.shape, 0.5)
    return img.astype(np.float32), (lam).astype(np.float32)
