"""Render functions over a model: ``render_views`` (many cameras at one time, coinciding cameras
once) and ``model_render_fn`` (the ``fn(camera, t) -> (H, W, 3)`` float32 RGB that evaluation,
videos, the restoration rows and the viewer's library path call). ``model`` is anything with
``at(t, camera_center=...) -> Snapshot`` (a SpacetimeGaussians, or a trainer's locked view of one).
"""
from __future__ import annotations

from typing import Callable

import numpy as np
import torch

from fixer4d.geometry.camera import Camera
from fixer4d.render.api import render


def render_views(model, cameras: list[Camera], t: float, backend: str = "auto",
                 background: "torch.Tensor | tuple[float, float, float] | None" = None,
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Render ``model`` at time ``t`` from every camera: rgb (F,H,W,3), depth (F,H,W), alpha (F,H,W).

    Cameras that coincide (same size, intrinsics and pose within 1e-9) are rendered once: a pair
    trajectory's endpoints are its reference cameras, which a restore request also needs.
    """
    rendered: list[tuple[Camera, tuple[np.ndarray, np.ndarray, np.ndarray]]] = []
    rgbs, depths, alphas = [], [], []
    with torch.no_grad():
        for cam in cameras:
            hit = next((r for c, r in rendered if _same_view(c, cam)), None)
            if hit is None:
                snap = model.at(t, camera_center=cam.center)
                out = render(snap, cam, background=background, backend=backend)
                hit = (out.rgb.clamp(0, 1).cpu().numpy(), out.depth.cpu().numpy(), out.alpha.cpu().numpy())
                rendered.append((cam, hit))
            rgbs.append(hit[0])
            depths.append(hit[1])
            alphas.append(hit[2])
    return np.stack(rgbs).astype(np.float32), np.stack(depths).astype(np.float32), np.stack(alphas).astype(np.float32)


def _same_view(a: Camera, b: Camera) -> bool:
    return (a.width == b.width and a.height == b.height and np.allclose(a.K, b.K, rtol=0.0, atol=1e-9)
            and np.allclose(a.c2w, b.c2w, rtol=0.0, atol=1e-9))


def model_render_fn(model, backend: str = "auto",
                    background: "tuple[float, float, float] | torch.Tensor | None" = None,
                    ) -> Callable[[Camera, float], np.ndarray]:
    """``fn(camera, t) -> (H, W, 3)`` float32 RGB in [0, 1] rendering ``model`` at clip time t."""
    bg = None if background is None else torch.as_tensor(background, dtype=torch.float32)

    def fn(camera: Camera, t: float) -> np.ndarray:
        return render_views(model, [camera], t, backend, bg)[0][0]

    return fn
