"""How much an export format loses: PSNR of the format's content rendered by fixer4d's own
renderer against the model's render, at sampled times and cameras.

Both images come from the same rasterizer, so the figure measures only what the format drops
or rounds (``fixer4d.model.formats.splatv``: SH bands, 8-bit colour, float16 fields, the
viewer's temporal cut), not differences between renderers.
"""
from __future__ import annotations

from typing import Callable, Sequence

import numpy as np
import torch

from fixer4d.eval.metrics import psnr
from fixer4d.geometry.camera import Camera
from fixer4d.model.snapshot import Snapshot
from fixer4d.model.spacetime import SpacetimeGaussians
from fixer4d.render.api import render

# Largest image side used for the comparison: the loss is per Gaussian, not per pixel, and a
# 320-pixel render keeps a 60k-Gaussian check to seconds on a CPU.
MAX_SIDE = 320


def _image(snap: Snapshot, camera: Camera, backend: str, background: torch.Tensor | None) -> np.ndarray:
    return render(snap, camera, background=background, backend=backend).rgb.clamp(0, 1).numpy()


def _sized(camera: Camera, max_side: int) -> Camera:
    side = max(camera.width, camera.height)
    return camera if side <= max_side else camera.scaled(max_side / side)


@torch.no_grad()
def reduction_psnr(model: SpacetimeGaussians, reduced_at: Callable[[float], Snapshot], cameras: Sequence[Camera],
                   times: Sequence[float], *, backend: str = "auto", background: Sequence[float] | None = None,
                   max_side: int = MAX_SIDE) -> dict:
    """PSNR (dB) of ``reduced_at(t)`` against ``model.at(t)``, every camera at every time.

    reduced_at: t -> the format's Snapshot at clip time t (view-independent). Cameras are scaled
    down to ``max_side`` pixels. Returns {"psnr_mean", "psnr_min", "samples": [{"camera",
    "time", "psnr"}], "max_side"}; an identical pair scores inf.
    """
    bg = None if background is None else torch.tensor(background, dtype=torch.float32)
    samples = []
    for t in times:
        reduced = reduced_at(float(t))
        for cam in cameras:
            cam = _sized(cam, max_side)
            ref = _image(model.snapshot(float(t), camera_center=cam.center), cam, backend, bg)
            got = _image(reduced, cam, backend, bg)
            samples.append({"camera": cam.name, "time": float(t), "psnr": psnr(got, ref)})
    values = [s["psnr"] for s in samples]
    return {"psnr_mean": float(np.mean(values)) if values else float("nan"),
            "psnr_min": float(np.min(values)) if values else float("nan"), "samples": samples, "max_side": max_side}
