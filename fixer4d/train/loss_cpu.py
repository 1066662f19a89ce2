"""L_STG = 0.8 L1 + 0.2 (1 - SSIM) and its gradient in one fused numba pass: the CPU training loss.

Same function as ``fixer4d.train.losses.stg_loss_torch`` (the readable reference: 11x11 Gaussian
window, sigma 1.5, zero padding, C1/C2 of Wang et al., optional per-pixel weight on both terms),
for one (H, W, 3) float32 render on the CPU. Why: the torch version is ~40 ops over full-image
tensors plus their autograd graph, all on torch's one intra-op thread during training; at
640x360 its forward + backward took 55 ms of a 340 ms training iteration (100k Gaussians, idle
machine), while everything around it (the rasterizer's kernels) ran on both cores. Here the
loss and its gradient w.r.t. the render are computed together in the forward, as row-parallel
separable convolutions; the backward only scales the stored gradient.

The gradient of the SSIM term (s = A1 A2 / (B1 B2), A1 = 2 mu_x mu_y + C1, A2 = 2 cov + C2,
B1 = mu_x^2 + mu_y^2 + C1, B2 = var_x + var_y + C2, with mu_x = G*x, E_xx = G*x^2, E_xy = G*xy):

    ds/dmu_x = 2 mu_y (A2 - A1) / (B1 B2) + 2 mu_x s (1/B2 - 1/B1)
    ds/dE_xx = -s / B2,   ds/dE_xy = 2 A1 / (B1 B2)
    dL/dx = G * D_mu + 2 x (G * D_xx) + y (G * D_xy)

where D_* = -0.2 w / N x ds/d* per pixel (N = 3 H W) and G* is the same zero-padded window
(symmetric, so it is its own adjoint). The L1 term's gradient is 0.8 w sign(x - y) / N
(sign(0) = 0, as torch's abs).

Arithmetic is float32 like the torch version; the sums over the image are float64. Agreement with
the reference: tests/train/test_loss_cpu.py (loss to 1e-6 relative, gradient to 1e-4 of its scale).
"""
from __future__ import annotations

import numpy as np
import torch

from fixer4d.jit import NUMBA_ERROR, njit, prange, torch_threads_kept
from fixer4d.train.ssim_window import LAMBDA_DSSIM, SSIM_C1, SSIM_C2, SSIM_WINDOW, gaussian_taps

_PAD = SSIM_WINDOW // 2  # zero padding on every side, so the SSIM map has the image's size


def unavailable_reason() -> str | None:
    """None when the fused kernel can run, else why not."""
    return NUMBA_ERROR


if njit is not None:

    @njit(inline="always")
    def _hconv_row(src, g, out):
        """out[j] = sum_k g[k] src[j + k] for a row ``src`` already padded by _PAD zeros per side."""
        w = out.shape[0]
        for j in range(w):
            out[j] = 0.0
        for k in range(g.shape[0]):
            gk = g[k]
            for j in range(w):
                out[j] += gk * src[j + k]

    @njit(cache=True, parallel=True, error_model="numpy")
    def _stg_fused(x, y, wt, g, c1, c2, lam, grad, sums):
        """x, y: (3, H, W) float32 planes; wt: (H, W) float32 weight; g: (11,) float32 taps.
        Writes grad (3, H, W) float32 = dL/dx and sums (3, H, 2) float64: per plane row, the sum
        of w |x - y| and of w s (the loss is assembled by the caller)."""
        n_c, h, w = x.shape
        f32 = np.float32
        one, two = f32(1.0), f32(2.0)
        inv_n = f32(1.0 / (n_c * h * w))
        k_l1 = (one - lam) * inv_n
        k_ss = -lam * inv_n
        # horizontal pass of the 5 moments into vertically padded planes
        hm = np.zeros((5, n_c, h + 2 * _PAD, w), np.float32)
        for cr in prange(n_c * h):
            c, r = cr // h, cr % h
            src = np.zeros((5, w + 2 * _PAD), np.float32)
            for j in range(w):
                a, b = x[c, r, j], y[c, r, j]
                src[0, j + _PAD] = a
                src[1, j + _PAD] = b
                src[2, j + _PAD] = a * a
                src[3, j + _PAD] = b * b
                src[4, j + _PAD] = a * b
            for m in range(5):
                _hconv_row(src[m], g, hm[m, c, r + _PAD])
        # vertical pass, the SSIM map, its per-pixel derivatives (vertically padded)
        dm = np.zeros((3, n_c, h + 2 * _PAD, w), np.float32)
        for cr in prange(n_c * h):
            c, r = cr // h, cr % h
            mom = np.zeros((5, w), np.float32)
            for m in range(5):
                for k in range(g.shape[0]):
                    gk = g[k]
                    row = hm[m, c, r + k]
                    for j in range(w):
                        mom[m, j] += gk * row[j]
            s_sum = 0.0
            l1_sum = 0.0
            for j in range(w):
                mx, my = mom[0, j], mom[1, j]
                mxx, myy, mxy = mx * mx, my * my, mx * my
                a1 = two * mxy + c1
                a2 = two * (mom[4, j] - mxy) + c2
                b1 = mxx + myy + c1
                b2 = (mom[2, j] - mxx) + (mom[3, j] - myy) + c2
                q = one / (b1 * b2)
                s = a1 * a2 * q
                wj = wt[r, j]
                s_sum += wj * s
                d = x[c, r, j] - y[c, r, j]
                l1_sum += wj * abs(d)
                u = k_ss * wj
                dm[0, c, r + _PAD, j] = u * (two * my * (a2 - a1) * q + two * mx * s * (one / b2 - one / b1))
                dm[1, c, r + _PAD, j] = u * (-s / b2)
                dm[2, c, r + _PAD, j] = u * (two * a1 * q)
            sums[c, r, 0] = l1_sum
            sums[c, r, 1] = s_sum
        # adjoint: vertical then horizontal pass of the derivatives, chain rule to x
        for cr in prange(n_c * h):
            c, r = cr // h, cr % h
            vert = np.zeros((3, w + 2 * _PAD), np.float32)
            for m in range(3):
                for k in range(g.shape[0]):
                    gk = g[k]
                    row = dm[m, c, r + k]
                    for j in range(w):
                        vert[m, j + _PAD] += gk * row[j]
            hor = np.empty((3, w), np.float32)
            for m in range(3):
                _hconv_row(vert[m], g, hor[m])
            for j in range(w):
                a, b = x[c, r, j], y[c, r, j]
                d = a - b
                sgn = one if d > 0 else (-one if d < 0 else f32(0.0))
                grad[c, r, j] = hor[0, j] + two * a * hor[1, j] + b * hor[2, j] + k_l1 * wt[r, j] * sgn


def _planes(t: torch.Tensor) -> np.ndarray:
    """(H, W, 3) tensor -> (3, H, W) contiguous float32 array."""
    return np.ascontiguousarray(t.detach().permute(2, 0, 1).numpy(), dtype=np.float32)


class _STGLossFused(torch.autograd.Function):
    @staticmethod
    def forward(ctx, render, target, weight):
        x, y = _planes(render), _planes(target)
        _, h, w = x.shape
        wt = np.ones((h, w), np.float32) if weight is None else np.ascontiguousarray(weight.detach().numpy(),
                                                                                     dtype=np.float32)
        g = gaussian_taps().astype(np.float32)
        grad = np.empty_like(x)
        sums = np.zeros((3, h, 2), np.float64)
        f32 = np.float32
        with torch_threads_kept():
            _stg_fused(x, y, wt, g, f32(SSIM_C1), f32(SSIM_C2), f32(LAMBDA_DSSIM), grad, sums)
        n = 3 * h * w
        l1_mean = sums[..., 0].sum() / n
        ssim_mean = sums[..., 1].sum() / n
        w_mean = 1.0 if weight is None else float(wt.astype(np.float64).mean())
        loss = (1.0 - LAMBDA_DSSIM) * l1_mean + LAMBDA_DSSIM * (w_mean - ssim_mean)
        ctx.grad = torch.from_numpy(grad).permute(1, 2, 0)
        return torch.tensor(loss, dtype=render.dtype)

    @staticmethod
    def backward(ctx, g_loss):
        return ctx.grad * g_loss, None, None


def fused_applies(render: torch.Tensor, target: torch.Tensor, weight: torch.Tensor | None) -> bool:
    """Whether ``stg_loss_fused`` computes this call: one (H, W, 3) float32 CPU render whose
    target and weight ((H, W) or None) need no gradient; anything else takes the torch path."""
    if NUMBA_ERROR is not None:
        return False
    if render.dim() != 3 or render.shape[-1] != 3 or render.shape != target.shape:
        return False
    if render.device.type != "cpu" or target.device.type != "cpu":
        return False
    if render.dtype != torch.float32 or target.dtype != torch.float32 or target.requires_grad:
        return False
    if min(render.shape[0], render.shape[1]) < 1:
        return False
    if weight is not None:
        if weight.shape != render.shape[:2] or weight.device.type != "cpu" or weight.requires_grad:
            return False
    return True


def stg_loss_fused(render: torch.Tensor, target: torch.Tensor, weight: torch.Tensor | None = None) -> torch.Tensor:
    """L_STG of a (H, W, 3) float32 CPU render and its target -> scalar tensor, differentiable
    w.r.t. ``render`` (first-order). weight: None or a non-negative (H, W) per-pixel weight.
    Call through ``fixer4d.train.losses.stg_loss``, which checks ``fused_applies``."""
    if NUMBA_ERROR is not None:
        from fixer4d.errors import BackendUnavailable

        raise BackendUnavailable(NUMBA_ERROR)
    return _STGLossFused.apply(render, target, weight)
