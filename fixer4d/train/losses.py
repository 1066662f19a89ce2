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


# Largest |value| for which the float32 SSIM moments keep their accuracy: the cancellation error
# of var = E[x^2] - mu^2 is ~eps32 x value^2 x (a few), 3e-5 at 8, far below C2 = 9e-4, so the
# denominator stays positive. Images are in [0, 1] and renders overshoot by little; inputs
# beyond this take the guarded path (float64, clamped), inputs within it the plain one.
FLOAT32_SAFE_VALUE = 8.0
# The guarded path clamps values to +-LOSS_VALUE_LIMIT (zero gradient beyond): a render that far
# outside [0, 1] has diverged, and the bound keeps the float64 moments, the loss and its
# gradients finite when cast back to float32.
LOSS_VALUE_LIMIT = 1e4


def _checked_pair(a: torch.Tensor, b: torch.Tensor, who: str) -> tuple[torch.Tensor, torch.Tensor, torch.dtype | None]:
    """Validate two images of one shape (non-empty, floating, finite) -> (a, b, cast_back).

    cast_back is None for the plain path. For |values| > FLOAT32_SAFE_VALUE it is the inputs'
    dtype and (a, b) are float64 copies clamped to +-LOSS_VALUE_LIMIT: the caller computes on
    them and casts the result back."""
    if not (torch.is_tensor(a) and torch.is_tensor(b)):
        raise InputError(f"{who}: expected torch tensors, got {type(a).__name__} and {type(b).__name__}")
    if a.shape != b.shape:
        raise InputError(f"{who}: image shapes differ: {tuple(a.shape)} vs {tuple(b.shape)}")
    if a.numel() == 0:
        raise InputError(f"{who}: images of shape {tuple(a.shape)} are empty; pass images with pixels")
    if not (a.is_floating_point() and b.is_floating_point()):
        raise InputError(f"{who}: expected float images in [0, 1], got {a.dtype} and {b.dtype}")
    with torch.no_grad():
        peak = float(torch.maximum(a.detach().abs().amax(), b.detach().abs().amax().to(a.dtype)))
    if not math.isfinite(peak):
        raise InputError(f"{who}: images contain NaN/inf; the render or its target is corrupt")
    if peak <= FLOAT32_SAFE_VALUE:
        return a, b, None
    limit = LOSS_VALUE_LIMIT
    return a.double().clamp(-limit, limit), b.double().clamp(-limit, limit), a.dtype


def _checked_weight(weight: torch.Tensor | None, who: str) -> None:
    """Raise InputError unless ``weight`` is None or a finite, non-negative float tensor."""
    if weight is None:
        return
    if not torch.is_tensor(weight) or not weight.is_floating_point():
        raise InputError(f"{who}: weight must be a float tensor of per-pixel weights >= 0")
    if weight.numel() == 0:
        return
    low = float(weight.detach().amin())
    if not (low >= 0.0 and bool(torch.isfinite(weight.detach()).all())):
        raise InputError(f"{who}: weight must be finite and >= 0 (got a minimum of {low}); "
                         "a negative weight would reward error")


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
    """Mean absolute difference of two non-empty float images of equal shape -> scalar tensor."""
    x, y, cast_back = _checked_pair(a, b, "l1")
    out = (x - y).abs().mean()
    return out if cast_back is None else out.to(cast_back)


def masked_l1(a: torch.Tensor, b: torch.Tensor, weight: torch.Tensor | None = None) -> torch.Tensor:
    """Per-pixel weighted L1 -> scalar tensor: mean over all pixels and channels of w * |a - b|.

    a, b: (H, W, 3) (or (B, H, W, 3)). weight: None (plain L1), or non-negative (H, W), (H, W, 1)
    or (H, W, 3) (batched likewise), e.g. a restorer's confidence in [0, 1]. The normalization is
    by the pixel count, not by the sum of weights, so a frame the restorer barely trusts pulls
    the model less instead of being rescaled to full strength.
    """
    if weight is None:
        return l1(a, b)
    x, y, cast_back = _checked_pair(a, b, "masked_l1")
    _checked_weight(weight, "masked_l1")
    out = _masked_l1(x, y, weight)
    return out if cast_back is None else out.to(cast_back)


def _masked_l1(a: torch.Tensor, b: torch.Tensor, weight: torch.Tensor) -> torch.Tensor:
    """``masked_l1`` on checked inputs."""
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
    a, b, cast_back = _checked_pair(a, b, "ssim")
    _checked_weight(weight, "ssim")
    out = _ssim(a, b, weight)
    return out if cast_back is None else out.to(cast_back)


def _ssim(a: torch.Tensor, b: torch.Tensor, weight: torch.Tensor | None = None) -> torch.Tensor:
    """``ssim`` on checked inputs."""
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
    a, b, cast_back = _checked_pair(a, b, "dssim")
    _checked_weight(weight, "dssim")
    out = _dssim(a, b, weight)
    return out if cast_back is None else out.to(cast_back)


def _dssim(a: torch.Tensor, b: torch.Tensor, weight: torch.Tensor | None = None) -> torch.Tensor:
    """``dssim`` on checked inputs."""
    if weight is None:
        return 1.0 - _ssim(a, b)
    return weight.mean() - _ssim(a, b, weight)


def stg_loss(render: torch.Tensor, target: torch.Tensor, weight: torch.Tensor | None = None) -> torch.Tensor:
    """L_STG = 0.8 * L1 + 0.2 * (1 - SSIM) of a render and its target, (H, W, 3) each -> scalar.

    weight: None, or a non-negative per-pixel weight (H, W) applied to both terms' per-pixel
    maps (normalized by the pixel count; all ones = the plain L_STG), e.g. more weight on the
    moving pixels (TrainingConfig.moving_loss_weight).

    A float32 CPU render goes through the fused numba kernel (fixer4d.train.loss_cpu: loss and
    gradient in one row-parallel pass); everything else, and FIXER4D_FUSED_LOSS=0, through
    ``stg_loss_torch``, the reference it is tested against."""
    x, y, cast_back = _checked_pair(render, target, "stg_loss")
    _checked_weight(weight, "stg_loss")
    if cast_back is None and os.environ.get(FUSED_SWITCH, "1") != "0":
        from fixer4d.train.loss_cpu import fused_applies, stg_loss_fused

        if fused_applies(render, target, weight):
            return stg_loss_fused(render, target, weight)
    out = _stg_loss(x, y, weight)
    return out if cast_back is None else out.to(cast_back)


def stg_loss_torch(render: torch.Tensor, target: torch.Tensor, weight: torch.Tensor | None = None) -> torch.Tensor:
    """``stg_loss`` in torch ops (any device, dtype or batch shape; differentiable w.r.t. both)."""
    x, y, cast_back = _checked_pair(render, target, "stg_loss_torch")
    _checked_weight(weight, "stg_loss_torch")
    out = _stg_loss(x, y, weight)
    return out if cast_back is None else out.to(cast_back)


def masked_l1_device(a: torch.Tensor, b: torch.Tensor, weight: torch.Tensor | None = None) -> torch.Tensor:
    """``masked_l1`` without reading a value back (stage 2's pseudo-views on a GPU; the caller
    vouches for the values, as for ``stg_loss_device``)."""
    _same_shape(a, b, "masked_l1_device")
    return (a - b).abs().mean() if weight is None else _masked_l1(a, b, weight)


def _same_shape(a: torch.Tensor, b: torch.Tensor, who: str) -> None:
    """InputError unless a and b are non-empty float tensors of one shape (checked on the host)."""
    if a.shape != b.shape or a.numel() == 0 or not a.is_floating_point():
        raise InputError(f"{who}: expected two non-empty float images of one shape, got "
                         f"{a.dtype} {tuple(a.shape)} and {b.dtype} {tuple(b.shape)}")


def stg_loss_device(render: torch.Tensor, target: torch.Tensor, weight: torch.Tensor | None = None) -> torch.Tensor:
    """``stg_loss_torch`` without reading a value back, for a GPU trainer's hot path (where each
    read waits for the device): shapes and dtypes are checked on the host, values are not. The
    caller vouches for them: targets and weights checked once when cached, the render's
    finiteness read with the loss every few steps. A render beyond FLOAT32_SAFE_VALUE, which
    ``stg_loss_torch`` would take to float64, has diverged; here it stays in float32 and shows as
    a non-finite loss at that check."""
    _same_shape(render, target, "stg_loss_device")
    return _stg_loss(render, target, weight)


def _stg_loss(render: torch.Tensor, target: torch.Tensor, weight: torch.Tensor | None) -> torch.Tensor:
    """``stg_loss_torch`` on checked inputs."""
    if weight is None:
        return (1.0 - LAMBDA_DSSIM) * (render - target).abs().mean() + LAMBDA_DSSIM * _dssim(render, target)
    return ((1.0 - LAMBDA_DSSIM) * _masked_l1(render, target, weight)
            + LAMBDA_DSSIM * _dssim(render, target, weight))


def psnr_torch(a: torch.Tensor, b: torch.Tensor) -> float:
    """PSNR in dB (data range 1) of two images of one shape, for progress bars; inf when
    identical (``fixer4d.psnr.psnr_from_mse``, the one PSNR formula)."""
    from fixer4d.psnr import psnr_from_mse

    if not (torch.is_tensor(a) and torch.is_tensor(b)) or a.shape != b.shape or a.numel() == 0:
        raise InputError(f"psnr_torch: expected two non-empty tensors of one shape, got "
                         f"{tuple(getattr(a, 'shape', ()))} and {tuple(getattr(b, 'shape', ()))}")
    mse = float(mean_squared_error(a, b))
    if not math.isfinite(mse):
        raise InputError(f"psnr_torch: the images contain NaN/inf or values too large to square (MSE {mse})")
    return psnr_from_mse(mse)


def mean_squared_error(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """The float64 mean squared difference of two images as a 0-d tensor on their device (what
    ``psnr_torch`` reads; a trainer reads it every few steps)."""
    return (a.detach().double() - b.detach().double()).pow(2).mean()
