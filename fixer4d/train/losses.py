"""Photometric losses for training: L1, SSIM (11x11 Gaussian window) and the STGS objective.

Images are torch tensors (H, W, 3) (or a batch (B, H, W, 3)), float, values in [0, 1].
SSIM follows 3DGS/STGS's training SSIM: an 11x11 Gaussian window with sigma 1.5, zero padding
of 5 pixels (so the map has the image's size), C1 = (0.01)^2, C2 = (0.03)^2 for data range 1,
mean over the map and the channels. The window is applied as two 1-D convolutions (rows, then
columns) on the 5 moment images stacked as channels of one grouped convolution, which keeps it
to two conv calls per SSIM.
"""
from __future__ import annotations

import math
import os

import torch
import torch.nn.functional as F

from fixer4d.errors import InputError
from fixer4d.train.ssim_window import LAMBDA_DSSIM, SSIM_C1, SSIM_C2, SSIM_WINDOW, gaussian_taps

# Environment switch: "0" keeps every stg_loss call on the torch reference (A/B timing, debugging).
FUSED_SWITCH = "FIXER4D_FUSED_LOSS"

_window_cache: dict[tuple[torch.device, torch.dtype], torch.Tensor] = {}


def _gaussian_1d(device: torch.device, dtype: torch.dtype) -> torch.Tensor:
    """(SSIM_WINDOW,) normalized Gaussian taps, cached per device/dtype."""
    key = (device, dtype)
    w = _window_cache.get(key)
    if w is None:
        w = torch.from_numpy(gaussian_taps()).to(device=device, dtype=dtype)
        _window_cache[key] = w
    return w


def _as_batch(a: torch.Tensor, b: torch.Tensor, who: str) -> tuple[torch.Tensor, torch.Tensor]:
    """Check shapes and return (B, 3, H, W) views of two (H, W, 3) or (B, H, W, 3) images."""
    if a.shape != b.shape:
        raise InputError(f"{who}: image shapes differ: {tuple(a.shape)} vs {tuple(b.shape)}")
    if a.dim() == 3:
        a, b = a.unsqueeze(0), b.unsqueeze(0)
    if a.dim() != 4 or a.shape[-1] != 3:
        raise InputError(f"{who}: expected (H, W, 3) or (B, H, W, 3) images, got {tuple(a.shape)}")
    return a.permute(0, 3, 1, 2), b.permute(0, 3, 1, 2)


def l1(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Mean absolute difference of two images of equal shape -> scalar tensor."""
    if a.shape != b.shape:
        raise InputError(f"l1: image shapes differ: {tuple(a.shape)} vs {tuple(b.shape)}")
    return (a - b).abs().mean()


def masked_l1(a: torch.Tensor, b: torch.Tensor, weight: torch.Tensor | None = None) -> torch.Tensor:
    """Per-pixel weighted L1 -> scalar tensor: mean over all pixels and channels of w * |a - b|.

    a, b: (H, W, 3) (or (B, H, W, 3)). weight: None (plain L1), or non-negative (H, W), (H, W, 1)
    or (H, W, 3) (batched likewise), e.g. a restorer's confidence in [0, 1]. The normalization is
    by the pixel count, not by the sum of weights, so a frame the restorer barely trusts pulls
    the model less instead of being rescaled to full strength.
    """
    if weight is None:
        return l1(a, b)
    if a.shape != b.shape:
        raise InputError(f"masked_l1: image shapes differ: {tuple(a.shape)} vs {tuple(b.shape)}")
    if weight.shape == a.shape[:-1]:
        weight = weight.unsqueeze(-1)
    if weight.dim() != a.dim() or weight.shape[:-1] != a.shape[:-1] or weight.shape[-1] not in (1, a.shape[-1]):
        raise InputError(f"masked_l1: weight shape {tuple(weight.shape)} does not match images {tuple(a.shape)}; "
                         "pass (H, W), (H, W, 1) or (H, W, 3)")
    return (weight * (a - b).abs()).mean()


def ssim(a: torch.Tensor, b: torch.Tensor, weight: torch.Tensor | None = None) -> torch.Tensor:
    """Mean SSIM of two images (H, W, 3) or (B, H, W, 3) in [0, 1] -> scalar tensor (1 = identical).

    weight: None, or a non-negative per-pixel weight (H, W) (batched (B, H, W)): the SSIM map is
    then averaged as mean(weight x map) (normalized by the pixel count, as ``masked_l1``).
    Differentiable w.r.t. both inputs.
    """
    x, y = _as_batch(a, b, "ssim")
    n, c, h, w = x.shape
    g = _gaussian_1d(x.device, x.dtype)
    pad = SSIM_WINDOW // 2
    # Moments as 5*C channels of one grouped convolution: E[x], E[y], E[x^2], E[y^2], E[xy].
    stack = torch.cat([x, y, x * x, y * y, x * y], dim=1)
    k = stack.shape[1]
    stack = F.conv2d(stack, g.view(1, 1, 1, SSIM_WINDOW).expand(k, 1, 1, SSIM_WINDOW), padding=(0, pad), groups=k)
    stack = F.conv2d(stack, g.view(1, 1, SSIM_WINDOW, 1).expand(k, 1, SSIM_WINDOW, 1), padding=(pad, 0), groups=k)
    mu_x, mu_y, e_xx, e_yy, e_xy = stack.split(c, dim=1)
    mu_xx, mu_yy, mu_xy = mu_x * mu_x, mu_y * mu_y, mu_x * mu_y
    var_x, var_y, cov = e_xx - mu_xx, e_yy - mu_yy, e_xy - mu_xy
    num = (2.0 * mu_xy + SSIM_C1) * (2.0 * cov + SSIM_C2)
    den = (mu_xx + mu_yy + SSIM_C1) * (var_x + var_y + SSIM_C2)
    smap = num / den
    if weight is None:
        return smap.mean()
    wt = weight if weight.dim() == 3 else weight.unsqueeze(0)
    if tuple(wt.shape) != (n, h, w):
        raise InputError(f"ssim: weight shape {tuple(weight.shape)} does not match images {tuple(a.shape)}")
    return (smap * wt.unsqueeze(1).to(smap.dtype)).mean()


def dssim(a: torch.Tensor, b: torch.Tensor, weight: torch.Tensor | None = None) -> torch.Tensor:
    """The training D-SSIM term 1 - SSIM (the STGS loss's convention, not the metric's (1 - SSIM)/2).

    weight: None, or a per-pixel weight (H, W): mean(weight x (1 - SSIM map))."""
    if weight is None:
        return 1.0 - ssim(a, b)
    return weight.mean() - ssim(a, b, weight)


def stg_loss(render: torch.Tensor, target: torch.Tensor, weight: torch.Tensor | None = None) -> torch.Tensor:
    """L_STG = 0.8 * L1 + 0.2 * (1 - SSIM) of a render and its target, (H, W, 3) each -> scalar.

    weight: None, or a non-negative per-pixel weight (H, W) applied to both terms' per-pixel
    maps (normalized by the pixel count; all ones = the plain L_STG), e.g. more weight on the
    moving pixels (Stage1Config.moving_loss_weight).

    A float32 CPU render goes through the fused numba kernel (fixer4d.train.loss_cpu: loss and
    gradient in one row-parallel pass); everything else, and FIXER4D_FUSED_LOSS=0, through
    ``stg_loss_torch``, the reference it is tested against."""
    if os.environ.get(FUSED_SWITCH, "1") != "0":
        from fixer4d.train.loss_cpu import fused_applies, stg_loss_fused

        if fused_applies(render, target, weight):
            return stg_loss_fused(render, target, weight)
    return stg_loss_torch(render, target, weight)


def stg_loss_torch(render: torch.Tensor, target: torch.Tensor, weight: torch.Tensor | None = None) -> torch.Tensor:
    """``stg_loss`` in torch ops (any device, dtype or batch shape; differentiable w.r.t. both)."""
    if weight is None:
        return (1.0 - LAMBDA_DSSIM) * l1(render, target) + LAMBDA_DSSIM * dssim(render, target)
    return (1.0 - LAMBDA_DSSIM) * masked_l1(render, target, weight) + LAMBDA_DSSIM * dssim(render, target, weight)


def psnr_torch(a: torch.Tensor, b: torch.Tensor) -> float:
    """PSNR in dB (data range 1) of two images, for progress bars; inf when identical."""
    mse = float((a.detach().double() - b.detach().double()).pow(2).mean())
    return math.inf if mse == 0.0 else -10.0 * math.log10(mse)
