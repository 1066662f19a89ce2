"""``RenderOutput``: what every rasterizer backend returns.

It lives in its own module so that ``render/api.py`` (the dispatcher) and the backends
(``render/gsplat_backend.py``, ...) both import it from below, and no backend has to import the
dispatcher that imports it (docs/design.md §3: imports only run downward).
"""
from __future__ import annotations

from dataclasses import dataclass

import torch


@dataclass
class RenderOutput:
    """One rendered view. Tensors live on the snapshot's device.

    rgb: (H, W, 3) colour composited over the background. alpha: (H, W) accumulated opacity.
    depth: (H, W) expected camera z-depth = sum_i w_i z_i / alpha, 0 where nothing was blended.
    radii: (N,) int32 splat radius in pixels, 0 = not drawn. means2d: (N, 2) projected centres
    in pixels; after backward its ``.grad`` holds dL/dmeans2d (densification statistics).
    n_fragments: number of (Gaussian, pixel) pairs blended (-1 when the backend cannot count).
    backend: the backend that actually rendered.
    """

    rgb: torch.Tensor
    alpha: torch.Tensor
    depth: torch.Tensor
    radii: torch.Tensor
    means2d: torch.Tensor
    n_fragments: int
    backend: str
