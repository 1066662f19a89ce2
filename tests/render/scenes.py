"""Small random scenes for the renderer tests (generated, never downloaded)."""
from __future__ import annotations

import numpy as np
import torch

from fixer4d.geometry.camera import Camera
from fixer4d.model.snapshot import Snapshot

FIELDS = ("means", "quats", "scales", "opacities", "colors")


def random_snapshot(n: int, seed: int = 0, dtype=torch.float64, spread: float = 1.0,
                    scale_range=(0.05, 0.3), opacity_range=(0.1, 0.9)) -> Snapshot:
    """n Gaussians in a cube of half-size ``spread`` around the origin."""
    g = torch.Generator().manual_seed(seed)
    lo, hi = scale_range
    olo, ohi = opacity_range
    return Snapshot(
        means=(torch.rand(n, 3, generator=g, dtype=dtype) * 2 - 1) * spread,
        quats=torch.randn(n, 4, generator=g, dtype=dtype),
        scales=torch.rand(n, 3, generator=g, dtype=dtype) * (hi - lo) + lo,
        opacities=torch.rand(n, generator=g, dtype=dtype) * (ohi - olo) + olo,
        colors=torch.rand(n, 3, generator=g, dtype=dtype),
    )


def front_camera(width: int = 24, height: int = 18, distance: float = 4.0, fov_deg: float = 50.0) -> Camera:
    """A camera on -z looking at the origin."""
    return Camera.look_at([0.0, 0.0, -distance], [0.0, 0.0, 0.0], fov_y=np.radians(fov_deg),
                          width=width, height=height, name="front")


def leaf(snapshot: Snapshot) -> Snapshot:
    """A copy whose fields are autograd leaves."""
    return Snapshot(*(getattr(snapshot, f).detach().clone().requires_grad_(True) for f in FIELDS))


def loss_weights(height: int, width: int, dtype, seed: int = 1):
    """Fixed random weights for a scalar loss over rgb, alpha and depth."""
    g = torch.Generator().manual_seed(seed)
    return (torch.randn(height, width, 3, generator=g, dtype=dtype),
            torch.randn(height, width, generator=g, dtype=dtype),
            torch.randn(height, width, generator=g, dtype=dtype))


def weighted_loss(out, weights) -> torch.Tensor:
    wr, wa, wd = weights
    return (out.rgb * wr).sum() + (out.alpha * wa).sum() + 0.1 * (out.depth * wd).sum()
