"""Oracle gradients through SpacetimeGaussians.at(t), for every parameter group, against
central finite differences (float64); and the fast kernel's through the same path.

The reference row of the parity table in docs/render.md (the rendering contract).
"""
from __future__ import annotations

import pytest
import torch

from fixer4d.model.spacetime import ModelConfig, SpacetimeGaussians
from fixer4d.render.api import render

from .scenes import front_camera, loss_weights, weighted_loss

FD_STEP = 1e-6


def _random_model(n: int, config: ModelConfig, seed: int, dtype=torch.float64) -> SpacetimeGaussians:
    model = SpacetimeGaussians(config, n, dtype=dtype)
    g = torch.Generator().manual_seed(seed)
    init = {
        "means": lambda s: (torch.rand(s, generator=g, dtype=dtype) * 2 - 1) * 0.7,
        "log_scales": lambda s: torch.log(torch.rand(s, generator=g, dtype=dtype) * 0.25 + 0.1),
        "quats": lambda s: torch.randn(s, generator=g, dtype=dtype),
        "opacity_logits": lambda s: torch.randn(s, generator=g, dtype=dtype),
        "colors": lambda s: torch.randn(s, generator=g, dtype=dtype) * 0.5,
        "sh_rest": lambda s: torch.randn(s, generator=g, dtype=dtype) * 0.1,
        "t_center": lambda s: torch.rand(s, generator=g, dtype=dtype),
        "t_log_scale": lambda s: torch.log(torch.rand(s, generator=g, dtype=dtype) * 0.5 + 0.3),
        "motion": lambda s: torch.randn(s, generator=g, dtype=dtype) * 0.3,
        "omega": lambda s: torch.randn(s, generator=g, dtype=dtype) * 0.5,
    }
    with torch.no_grad():
        for name in model.param_names():
            p = getattr(model, name)
            p.copy_(init[name](tuple(p.shape)))
    return model


@pytest.mark.parametrize("t", [0.4, -0.25, 1.3])  # inside, before and beyond the clip
def test_every_parameter_group_matches_finite_differences(t):
    cam = front_camera(18, 14)
    model = _random_model(10, ModelConfig(motion_degree=3, rotation_velocity=True, temporal_opacity=True,
                                          sh_degree=1), seed=int(t * 100) % 7)
    weights = loss_weights(14, 18, torch.float64, seed=3)

    def loss():
        return weighted_loss(render(model.at(t, camera_center=cam.center), cam, backend="reference"), weights)

    model.zero_grad()
    loss().backward()
    g = torch.Generator().manual_seed(0)
    for name in model.param_names():
        p = getattr(model, name)
        grad = p.grad.detach().reshape(-1).clone()
        idx = torch.randperm(p.numel(), generator=g)[:5]
        idx = torch.unique(torch.cat([idx, grad.abs().topk(min(3, grad.numel())).indices]))
        for i in idx.tolist():
            vals = []
            for sign in (1.0, -1.0):
                with torch.no_grad():
                    p.view(-1)[i] += sign * FD_STEP
                    vals.append(float(loss()))
                    p.view(-1)[i] -= sign * FD_STEP
            fd = (vals[0] - vals[1]) / (2 * FD_STEP)
            assert abs(fd - float(grad[i])) <= 1e-5 + 1e-4 * abs(fd), (name, i, fd, float(grad[i]))


def test_fast_kernel_gradients_through_model_match_oracle():
    cam = front_camera(32, 24)
    model = _random_model(120, ModelConfig(), seed=2, dtype=torch.float32)
    weights = loss_weights(24, 32, torch.float32, seed=4)
    grads = {}
    for backend in ("cpu", "reference"):
        model.zero_grad()
        weighted_loss(render(model.at(0.3), cam, backend=backend), weights).backward()
        grads[backend] = {n: getattr(model, n).grad.clone() for n in model.param_names()}
    for name, ref in grads["reference"].items():
        err = float((grads["cpu"][name] - ref).norm())
        assert err <= 1e-3 * float(ref.norm()) + 1e-5, (name, err, float(ref.norm()))
