"""Evaluation metrics against known values and against scikit-image called directly."""
import math

import numpy as np
import pytest
from skimage.metrics import structural_similarity

from fixer4d.errors import InputError
from fixer4d.eval import metrics as M


def _pair(h=40, w=48, seed=0):
    rng = np.random.default_rng(seed)
    a = rng.random((h, w, 3), dtype=np.float32)
    b = np.clip(a + rng.normal(0, 0.08, a.shape), 0, 1).astype(np.float32)
    return a, b


def test_psnr_from_known_mse():
    a = np.full((10, 12, 3), 0.3, np.float32)
    assert M.psnr(a, a + np.float32(0.1)) == pytest.approx(20.0, abs=1e-4)  # MSE 1e-2
    b = a.copy()
    b[0, 0, 0] += 0.6  # MSE = 0.36 / 360 = 1e-3 -> 30 dB
    assert M.psnr(a, b) == pytest.approx(30.0, abs=1e-4)
    assert M.psnr(a, a) == math.inf


def test_dssim_zero_for_identical_images():
    a, _ = _pair()
    assert M.dssim1(a, a) == pytest.approx(0.0, abs=1e-12)
    assert M.dssim2(a, a) == pytest.approx(0.0, abs=1e-12)


def test_dssim_agrees_with_skimage_called_directly():
    a, b = _pair()
    s1 = structural_similarity(a, b, data_range=1.0, channel_axis=-1)  # defaults: 7x7 uniform window
    s2 = structural_similarity(a, b, data_range=2.0, channel_axis=-1)
    assert M.dssim1(a, b) == pytest.approx((1 - s1) / 2, abs=1e-12)
    assert M.dssim2(a, b) == pytest.approx((1 - s2) / 2, abs=1e-12)
    # a larger data range grows the stabilizing constants, so SSIM rises and DSSIM2 < DSSIM1
    assert 0 < M.dssim2(a, b) < M.dssim1(a, b)


def test_image_metrics_keys_and_types():
    a, b = _pair()
    m = M.image_metrics(a, b)
    assert set(m) == {"psnr", "dssim1", "dssim2", "lpips"}
    assert m["psnr"] == pytest.approx(M.psnr(a, b))
    assert m["lpips"] is None or (isinstance(m["lpips"], float) and m["lpips"] > 0)


def test_bad_inputs_raise_clear_errors():
    a, b = _pair()
    with pytest.raises(InputError, match="equal shape"):
        M.psnr(a, b[:-1])
    bad = a.copy()
    bad[0, 0, 0] = np.nan
    with pytest.raises(InputError, match="NaN"):
        M.dssim1(bad, b)


def test_masked_psnr_and_region_metrics():
    rng = np.random.default_rng(0)
    gt = rng.uniform(0.2, 0.8, (40, 50, 3)).astype(np.float32)
    mask = np.zeros((40, 50), bool)
    mask[10:20, 5:25] = True
    pred = gt + np.where(mask[..., None], 0.1, 0.01).astype(np.float32)
    assert M.masked_psnr(pred, gt, mask) == pytest.approx(20.0, abs=1e-4)
    assert M.masked_psnr(pred, gt, ~mask) == pytest.approx(40.0, abs=1e-4)
    assert M.masked_psnr(pred, gt, np.zeros_like(mask)) is None
    assert M.masked_psnr(gt, gt, mask) == math.inf
    assert M.masked_psnr(pred, gt, np.ones_like(mask)) == pytest.approx(M.psnr(pred, gt))
    r = M.region_metrics(pred, gt, mask)
    assert r["psnr_dynamic"] == pytest.approx(20.0, abs=1e-4) and r["psnr_static"] == pytest.approx(40.0, abs=1e-4)
    assert r["ssim_dynamic"] < r["ssim_static"] < 1.0
    # The SSIM map's mean is the image SSIM that DSSIM1 reports.
    assert 1.0 - 2.0 * M.dssim1(pred, gt) == pytest.approx(float(M.ssim_map(pred, gt)[3:-3, 3:-3].mean()), abs=1e-6)
    everything = M.region_metrics(pred, gt, np.ones_like(mask))
    assert everything["ssim_dynamic"] == pytest.approx(1.0 - 2.0 * M.dssim1(pred, gt), abs=1e-6)
    empty = M.region_metrics(pred, gt, np.zeros_like(mask))
    assert empty["psnr_dynamic"] is None and empty["ssim_dynamic"] is None
    with pytest.raises(InputError, match="mask shape"):
        M.masked_psnr(pred, gt, mask[:, :10])
