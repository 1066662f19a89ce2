"""A small spacetime model with every effect switched on, and cameras that see it (output tests)."""
from __future__ import annotations

import numpy as np
import torch

from fixer4d.geometry.camera import Camera
from fixer4d.model.spacetime import ModelConfig, SpacetimeGaussians

FULL = ModelConfig(motion_degree=3, rotation_velocity=True, temporal_opacity=True, sh_degree=1)


def small_model(n: int = 400, config: ModelConfig = FULL, seed: int = 0, static_fraction: float = 0.3,
                sh_scale: float = 0.15) -> SpacetimeGaussians:
    """n Gaussians in a unit ball: a ``static_fraction`` of them static, the others moving (cubic
    motion, spin), fading in and out over the clip (temporal stds 0.05..0.5 so some rows are
    invisible at some frames), with view-dependent colour when the config has SH."""
    rng = np.random.default_rng(seed)
    pts = rng.normal(size=(n, 3)) * 0.45
    model = SpacetimeGaussians.from_points(pts, rng.uniform(0.1, 0.9, size=(n, 3)), rng.uniform(0, 1, size=n), config,
                                           opacity=0.7, scales=rng.uniform(0.03, 0.1, size=(n, 3)),
                                           dynamic=rng.uniform(size=n) >= static_fraction)
    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        model.quats.copy_(torch.randn(n, 4, generator=g))
        model.opacity_logits.copy_(torch.randn(n, generator=g) + 1.0)
        if config.motion_degree:
            model.motion.copy_(torch.randn(model.motion.shape, generator=g) * 0.3)
        if config.rotation_velocity:
            model.omega.copy_(torch.randn(n, 4, generator=g) * 0.5)
        if config.temporal_opacity:
            model.t_log_scale.copy_(torch.log(torch.rand(n, generator=g) * 0.45 + 0.05))
        if config.sh_degree:
            model.sh_rest.copy_(torch.randn(model.sh_rest.shape, generator=g) * sh_scale)
    return model


def front_camera(width: int = 64, height: int = 48, name: str = "front", azimuth_deg: float = 0.0) -> Camera:
    """A camera 3 units from the origin, looking at it (image up = world -y)."""
    a = np.radians(azimuth_deg)
    eye = 3.0 * np.array([np.sin(a), 0.0, -np.cos(a)])
    return Camera.look_at(eye, [0.0, 0.0, 0.0], up=(0.0, -1.0, 0.0), fov_y=np.radians(45.0), width=width,
                          height=height, name=name)
