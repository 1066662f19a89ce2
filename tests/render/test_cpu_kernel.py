"""Internals of the fast kernel that the parity tests do not pin down directly (cpu row of the
parity table in docs/render.md)."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from fixer4d.render import cpu
from fixer4d.render import cpu_kernels as kernels
from fixer4d.render.api import render

from .scenes import front_camera, leaf, random_snapshot

pytestmark = pytest.mark.skipif(cpu.unavailable_reason() is not None, reason="numba missing")


def test_exp_neg_error_bound():
    """The kernels' explicit float32 exp(-power) (vectorizable, no libm call) stays within its
    stated bound (cpu_kernels.EXP_MAX_ULP, measured exhaustively) on a dense sample of the whole range
    the blending uses, power in [0, POWER_MAX] and up to the clamp at 6, and is mostly
    correctly rounded. (Threshold decisions can then differ from the oracle's exp in rare
    fragments; the parity tests show they stay within their tolerances.)"""
    from numba import njit

    @njit
    def run(x, out):
        for i in range(x.shape[0]):
            out[i] = kernels._exp_neg(x[i])

    x = np.linspace(0.0, 6.0, 2_000_001, dtype=np.float32)
    tiny = np.float32(2.0) ** -np.arange(1, 150, dtype=np.float32)  # down to subnormal powers
    x = np.concatenate([x, np.nextafter(x, np.float32(7)), tiny, np.float32([0.0, -0.0, kernels._POWER_MAX])])
    x = x[x <= 6.0]  # beyond, the argument is clamped (results there are never used)
    got = np.empty_like(x)
    run(x, got)
    exact = np.exp(-x.astype(np.float64))
    ulp = np.exp2(np.floor(np.log2(exact)) - 23)  # float32 spacing in the exact value's binade
    err = np.abs(got.astype(np.float64) - exact) / ulp
    assert err.max() <= kernels.EXP_MAX_ULP
    assert kernels.EXP_MAX_ULP < 1.0  # faithful: the result is one of the two floats around exp(-power)
    # 89.9 % of this sample is correctly rounded (the rest 1 ulp off, within the bound)
    assert (got == exact.astype(np.float32)).mean() > 0.85


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


def test_row_test_never_skips_a_blending_pixel():
    """_active_rows may only skip tile rows where no pixel can pass the per-pixel tests: check it
    against those tests (float32, as the kernels evaluate them) on random splats, needles among
    them, at every tile they are binned to."""
    rng = np.random.default_rng(5)
    n, width, height = 120, 64, 48
    means = rng.uniform([-20, -20], [width + 20, height + 20], (n, 2))
    long_sd = np.exp(rng.uniform(np.log(0.3), np.log(3000.0), n))  # up to needles 9000 px long
    short_sd = np.exp(rng.uniform(np.log(0.55), np.log(6.0), n))
    ang = rng.uniform(0, np.pi, n)
    c, s = np.cos(ang), np.sin(ang)
    ca = (long_sd * c) ** 2 + (short_sd * s) ** 2
    cb = (long_sd ** 2 - short_sd ** 2) * c * s
    cc = (long_sd * s) ** 2 + (short_sd * c) ** 2
    det = ca * cc - cb * cb
    conic = torch.tensor(np.stack([cc / det, -cb / cc, 1.0 / cc], 1), dtype=torch.float32)
    op = torch.tensor(rng.uniform(0.004, 1.0, n), dtype=torch.float32)
    rec = cpu._records(torch.tensor(means, dtype=torch.float32), conic, op, torch.rand(n, 3),
                       torch.tensor(rng.uniform(1, 5, n), dtype=torch.float32))
    radii = np.full(n, 10 ** 6, np.int64)
    order = np.arange(n, dtype=np.int64)
    offsets, ids = kernels.bin_tiles(rec, radii, order, width, height, kernels._TILE, 2)
    n_tx = (width + kernels._TILE - 1) // kernels._TILE
    gate = np.full(kernels._TILE, kernels._GATE_OPEN, np.float32)
    act = np.zeros(kernels._TILE, np.bool_)
    checked = skipped = 0
    f = np.float32
    for t in range(len(offsets) - 1):
        x0, y0 = (t % n_tx) * kernels._TILE, (t // n_tx) * kernels._TILE
        px = np.arange(x0, x0 + kernels._TILE, dtype=f) + f(0.5)
        for g in ids[offsets[t]:offsets[t + 1]]:
            kernels._active_rows(rec, g, f(0), x0, y0, min(kernels._TILE, height - y0), gate, act)
            mx, my, a, r, q, o = (rec[g, k] for k in (kernels.R_MX, kernels.R_MY, kernels.R_A, kernels.R_R,
                                                      kernels.R_Q, kernels.R_O))
            for row in range(min(kernels._TILE, height - y0)):
                dx = px - mx
                dy = f(y0 + row) + f(0.5) - my
                e = dx + r * dy
                power = f(0.5) * (a * e * e + q * dy * dy)
                alpha = np.minimum(o * np.exp(-power.astype(np.float64)).astype(f), f(0.99))
                blends = (power <= kernels._POWER_MAX) & (alpha >= kernels.ALPHA_MIN32)
                checked += 1
                skipped += not act[row]
                assert act[row] or not blends.any(), (t, g, row)
    assert checked > 3_000 and skipped > checked // 10  # the test has teeth: many rows are skipped


def test_parallel_binning_keeps_the_depth_order_for_any_thread_count():
    """bin_tiles splits the depth order into chunks over threads: every tile's list must still be
    the depth order restricted to the splats whose box touches the tile, whatever the count."""
    rng = np.random.default_rng(11)
    n, width, height = 700, 96, 72
    means = torch.tensor(rng.uniform([-10, -10], [width + 10, height + 10], (n, 2)), dtype=torch.float32)
    sd = rng.uniform(0.5, 12.0, n)
    conic = torch.tensor(np.stack([1.0 / sd ** 2, np.zeros(n), 1.0 / sd ** 2], 1), dtype=torch.float32)
    op = torch.tensor(rng.uniform(0.004, 1.0, n), dtype=torch.float32)
    depth = torch.tensor(rng.uniform(1, 5, n), dtype=torch.float32)
    radii = np.ceil(3 * sd).astype(np.int64)
    order = np.argsort(depth.numpy(), kind="stable").astype(np.int64)
    results = []
    for threads in (1, 2, 3, 8):
        rec = cpu._records(means, conic, op, torch.rand(n, 3), depth)
        results.append(kernels.bin_tiles(rec, radii, order, width, height, kernels._TILE, threads))
    offsets, ids = results[0]
    for o, i in results[1:]:
        np.testing.assert_array_equal(o, offsets)
        np.testing.assert_array_equal(i, ids)
    rank = np.empty(n, np.int64)
    rank[order] = np.arange(n)
    assert len(ids) > n  # splats span several tiles
    for t in range(len(offsets) - 1):
        assert (np.diff(rank[ids[offsets[t]:offsets[t + 1]]]) > 0).all()
