"""The fused CPU training loss (fixer4d.train.loss_cpu) against the torch reference."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from fixer4d.train import loss_cpu
from fixer4d.train.losses import FUSED_SWITCH, stg_loss, stg_loss_torch

pytestmark = pytest.mark.skipif(loss_cpu.unavailable_reason() is not None, reason="numba unavailable")


def _pair(h, w, seed, smooth=False):
    g = torch.Generator().manual_seed(seed)
    x = torch.rand(h, w, 3, generator=g)
    y = torch.rand(h, w, 3, generator=g)
    if smooth:  # a render near its target: the regime training is in (SSIM close to 1)
        x = (y + 0.02 * (x - 0.5)).clamp(0, 1)
    return x.requires_grad_(True), y


def _loss_and_grad(fn, x, y, weight):
    loss = fn(x, y, weight)
    (grad,) = torch.autograd.grad(loss, x)
    return float(loss.detach()), grad


@pytest.mark.parametrize("h,w", [(1, 1), (3, 17), (11, 11), (37, 64), (90, 160)])
@pytest.mark.parametrize("weighted", [False, True])
@pytest.mark.parametrize("smooth", [False, True])
def test_fused_matches_the_torch_reference(h, w, weighted, smooth):
    x, y = _pair(h, w, seed=h * 1000 + w, smooth=smooth)
    weight = torch.rand(h, w, generator=torch.Generator().manual_seed(7)) * 3.0 if weighted else None
    assert loss_cpu.fused_applies(x, y, weight)
    lf, gf = _loss_and_grad(loss_cpu.stg_loss_fused, x, y, weight)
    lt, gt = _loss_and_grad(stg_loss_torch, x, y, weight)
    assert lf == pytest.approx(lt, rel=1e-5, abs=1e-7)
    scale = float(gt.abs().max())
    assert float((gf - gt).abs().max()) <= 1e-4 * scale + 1e-12


def test_fused_gradient_is_the_derivative_float64_check():
    """Central differences of the float64 reference at a few pixels agree with the fused
    float32 gradient (so both can't be wrong the same way)."""
    x, y = _pair(12, 15, seed=3, smooth=True)
    _, gf = _loss_and_grad(loss_cpu.stg_loss_fused, x, y, None)
    xd, yd = x.detach().double(), y.double()
    eps = 1e-6
    for (r, c, ch) in [(0, 0, 0), (5, 7, 1), (11, 14, 2), (6, 0, 2)]:
        plus, minus = xd.clone(), xd.clone()
        plus[r, c, ch] += eps
        minus[r, c, ch] -= eps
        fd = (float(stg_loss_torch(plus, yd)) - float(stg_loss_torch(minus, yd))) / (2 * eps)
        assert float(gf[r, c, ch]) == pytest.approx(fd, rel=2e-3, abs=1e-7)


def test_backward_scales_with_the_upstream_gradient():
    x, y = _pair(20, 24, seed=5)
    (g1,) = torch.autograd.grad(loss_cpu.stg_loss_fused(x, y), x)
    (g3,) = torch.autograd.grad(3.0 * loss_cpu.stg_loss_fused(x, y), x)
    torch.testing.assert_close(g3, 3.0 * g1)


def test_stg_loss_dispatch_and_switch(monkeypatch):
    x, y = _pair(16, 16, seed=1)
    calls = []
    real = loss_cpu.stg_loss_fused
    monkeypatch.setattr(loss_cpu, "stg_loss_fused", lambda *a: calls.append(1) or real(*a))
    stg_loss(x, y)
    assert calls == [1]
    monkeypatch.setenv(FUSED_SWITCH, "0")
    stg_loss(x, y)
    assert calls == [1]


@pytest.mark.parametrize("case", ["float64", "batched", "target_grad", "weight_hw3", "weight_grad"])
def test_other_calls_take_the_torch_path(case):
    x, y = _pair(8, 9, seed=2)
    weight = None
    if case == "float64":
        x, y = x.detach().double().requires_grad_(True), y.double()
    elif case == "batched":
        x, y = x.detach().unsqueeze(0).requires_grad_(True), y.unsqueeze(0)
    elif case == "target_grad":
        y = y.clone().requires_grad_(True)
    elif case == "weight_hw3":
        weight = torch.ones(8, 9, 3)
    elif case == "weight_grad":
        weight = torch.ones(8, 9, requires_grad=True)
    assert not loss_cpu.fused_applies(x, y, weight)
    if case != "weight_hw3":  # masked SSIM takes (H, W) weights only
        assert np.isfinite(float(stg_loss(x, y, weight).detach()))


def test_fused_is_deterministic_and_independent_of_threads():
    import numba

    x, y = _pair(45, 70, seed=9)
    base = numba.get_num_threads()
    out = []
    for n in sorted({1, base}):
        numba.set_num_threads(n)
        try:
            out.append(_loss_and_grad(loss_cpu.stg_loss_fused, x, y, None))
        finally:
            numba.set_num_threads(base)
    out.append(_loss_and_grad(loss_cpu.stg_loss_fused, x, y, None))
    for loss, grad in out[1:]:
        assert loss == out[0][0]
        assert torch.equal(grad, out[0][1])
