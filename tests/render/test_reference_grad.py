"""The oracle's autograd gradients against central finite differences, float64.

The reference row of the parity table in docs/render.md (the rendering contract).
"""
from __future__ import annotations

import pytest
import torch

from fixer4d.render.api import render

from .scenes import FIELDS, front_camera, leaf, loss_weights, random_snapshot, weighted_loss

# central differences in float64: truncation ~ h^2, round-off ~ 1e-16 / h
FD_STEP = 1e-6


def _fd_check(snap, cam, weights, field, n_checks=12, seed=0):
    snap = leaf(snap)
    out = render(snap, cam, backend="reference")
    weighted_loss(out, weights).backward()
    grad = getattr(snap, field).grad.detach().reshape(-1)
    base = getattr(snap, field).detach()
    g = torch.Generator().manual_seed(seed)
    idx = torch.randperm(base.numel(), generator=g)[:n_checks]
    # also check the entries with the largest analytic gradient
    idx = torch.unique(torch.cat([idx, grad.abs().topk(min(4, grad.numel())).indices]))
    for i in idx.tolist():
        vals = []
        for sign in (1.0, -1.0):
            pert = base.clone().reshape(-1)
            pert[i] += sign * FD_STEP
            s2 = leaf(snap)
            setattr(s2, field, pert.reshape(base.shape))
            with torch.no_grad():
                vals.append(float(weighted_loss(render(s2, cam, backend="reference"), weights)))
        fd = (vals[0] - vals[1]) / (2 * FD_STEP)
        assert abs(fd - float(grad[i])) <= 1e-5 + 1e-4 * abs(fd), (field, i, fd, float(grad[i]))


@pytest.mark.parametrize("field", FIELDS)
@pytest.mark.parametrize("seed", [0, 1])
def test_oracle_matches_finite_differences(field, seed):
    cam = front_camera(20, 16)
    snap = random_snapshot(12, seed=seed, spread=0.8, scale_range=(0.1, 0.4))
    _fd_check(snap, cam, loss_weights(16, 20, torch.float64, seed=seed + 5), field, seed=seed)


def test_oracle_gradients_with_background_and_early_stop():
    """Dense, opaque scene: many pixels terminate early; gradients still match."""
    cam = front_camera(16, 12)
    snap = random_snapshot(30, seed=3, spread=0.3, scale_range=(0.2, 0.5), opacity_range=(0.6, 0.98))
    w = loss_weights(12, 16, torch.float64, seed=9)
    for field in FIELDS:
        _fd_check(snap, cam, w, field, n_checks=6, seed=4)
