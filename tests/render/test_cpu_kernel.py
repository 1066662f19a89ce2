"""Internals of the fast kernel that the parity tests do not pin down directly."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from fixer4d.render import cpu
from fixer4d.render.api import render

from .scenes import front_camera, leaf, random_snapshot

pytestmark = pytest.mark.skipif(cpu.unavailable_reason() is not None, reason="numba missing")


def test_exp_neg_is_correctly_rounded_expf():
    """The kernels' explicit exp(-power) (vectorizable, no libm call) rounds like a correct expf
    on the whole range the blending uses, so alpha thresholds decide as with libm."""
    from numba import njit

    @njit
    def run(x, out):
        for i in range(x.shape[0]):
            out[i] = cpu._exp_neg(x[i])

    x = np.linspace(0.0, 6.0, 400_001, dtype=np.float32)
    x = np.concatenate([x, np.nextafter(x, np.float32(7)), np.float32([-1e-7, 4.5])])
    x = x[x <= 6.0]  # beyond, the argument is clamped (results there are never used)
    got = np.empty_like(x)
    run(x, got)
    exact = np.exp(-x.astype(np.float64))
    ulp = np.abs(got.astype(np.float64) - exact) / np.spacing(exact.astype(np.float32)).astype(np.float64)
    assert ulp.max() <= 0.5 + 1e-6
    assert (got == exact.astype(np.float32)).mean() > 0.9999


def test_render_keeps_torch_thread_count():
    """numba shares libgomp with torch: a render must not change torch's intra-op threads."""
    before = torch.get_num_threads()
    try:
        torch.set_num_threads(1)
        snap = leaf(random_snapshot(50, seed=3, dtype=torch.float32))
        out = render(snap, front_camera(16, 12), backend="cpu")
        out.rgb.sum().backward()
        assert torch.get_num_threads() == 1
    finally:
        torch.set_num_threads(before)


def test_tile_orders_balance_work():
    offsets = np.cumsum(np.r_[0, np.random.default_rng(0).integers(0, 500, 301)]).astype(np.int64)
    by_work, dealt = cpu._tile_orders(offsets, 2)
    work = np.diff(offsets)
    assert sorted(by_work.tolist()) == list(range(301)) and sorted(dealt.tolist()) == list(range(301))
    assert (np.diff(work[by_work]) <= 0).all()
    half = (301 + 1) // 2  # prange's static split: the first block goes to thread 0
    a, b = work[dealt[:half]].sum(), work[dealt[half:]].sum()
    assert abs(a - b) <= work.max()
