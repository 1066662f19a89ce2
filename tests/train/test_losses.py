"""Training losses: L1, masked L1, separable Gaussian SSIM, L_STG."""
import numpy as np
import pytest
import torch
from scipy.ndimage import correlate

from fixer4d.errors import InputError
from fixer4d.train import losses


def _images(h=24, w=32, seed=0, dtype=torch.float32):
    g = torch.Generator().manual_seed(seed)
    a = torch.rand(h, w, 3, generator=g, dtype=torch.float64)
    b = (a + 0.2 * torch.rand(h, w, 3, generator=g, dtype=torch.float64)).clamp(0, 1)
    return a.to(dtype), b.to(dtype)


def _ssim_direct(a: np.ndarray, b: np.ndarray) -> float:
    """Independent SSIM: full 2-D 11x11 Gaussian window, zero padding, numpy/scipy in float64."""
    x = np.arange(11) - 5.0
    g = np.exp(-x ** 2 / (2 * 1.5 ** 2))
    k = np.outer(g, g)
    k /= k.sum()
    vals = []
    for c in range(3):
        p, q = a[..., c], b[..., c]
        f = lambda im: correlate(im, k, mode="constant", cval=0.0)  # noqa: E731
        mx, my = f(p), f(q)
        vx, vy, cxy = f(p * p) - mx ** 2, f(q * q) - my ** 2, f(p * q) - mx * my
        c1, c2 = 0.01 ** 2, 0.03 ** 2
        vals.append(((2 * mx * my + c1) * (2 * cxy + c2)) / ((mx ** 2 + my ** 2 + c1) * (vx + vy + c2)))
    return float(np.mean(vals))


def test_ssim_identical_is_one_and_grad_finite():
    a, _ = _images()
    x = a.clone().requires_grad_()
    s = losses.ssim(x, a)
    assert abs(s.item() - 1.0) < 1e-5
    (1 - s).backward()
    assert torch.isfinite(x.grad).all()


def test_ssim_matches_direct_2d_window():
    a, b = _images(dtype=torch.float64)
    ours = float(losses.ssim(a, b))
    ref = _ssim_direct(a.numpy(), b.numpy())
    assert ours < 0.99  # the pair is genuinely different
    assert abs(ours - ref) < 1e-10


def test_ssim_batched_equals_mean_of_singles():
    a1, b1 = _images(seed=1, dtype=torch.float64)
    a2, b2 = _images(seed=2, dtype=torch.float64)
    batched = float(losses.ssim(torch.stack([a1, a2]), torch.stack([b1, b2])))
    assert abs(batched - 0.5 * (float(losses.ssim(a1, b1)) + float(losses.ssim(a2, b2)))) < 1e-12


def test_ssim_gradient_matches_finite_difference_float64():
    a, b = _images(h=12, w=16, dtype=torch.float64)
    x = a.clone().requires_grad_()
    losses.ssim(x, b).backward()
    g = torch.Generator().manual_seed(3)
    for _ in range(3):
        v = torch.randn(a.shape, generator=g, dtype=torch.float64)
        eps = 1e-6
        fd = (float(losses.ssim(a + eps * v, b)) - float(losses.ssim(a - eps * v, b))) / (2 * eps)
        assert abs(fd - float((x.grad * v).sum())) < 1e-6 * max(1.0, abs(fd))


def test_stg_loss_is_weighted_sum():
    a, b = _images()
    a.requires_grad_()
    loss = losses.stg_loss(a, b)
    expect = 0.8 * (a - b).abs().mean() + 0.2 * (1 - losses.ssim(a, b))
    assert torch.allclose(loss, expect)
    loss.backward()
    assert torch.isfinite(a.grad).all() and a.grad.abs().sum() > 0


def test_l1_and_masked_l1_known_values():
    a = torch.zeros(4, 6, 3)
    b = torch.full((4, 6, 3), 0.5)
    assert float(losses.l1(a, b)) == pytest.approx(0.5)
    assert float(losses.masked_l1(a, b)) == pytest.approx(0.5)
    assert float(losses.masked_l1(a, b, torch.ones(4, 6))) == pytest.approx(0.5)
    assert float(losses.masked_l1(a, b, torch.zeros(4, 6, 1))) == 0.0
    half = torch.zeros(4, 6)
    half[:, :3] = 1.0
    assert float(losses.masked_l1(a, b, half)) == pytest.approx(0.25)
    per_channel = torch.zeros(4, 6, 3)
    per_channel[..., 0] = 1.0
    assert float(losses.masked_l1(a, b, per_channel)) == pytest.approx(0.5 / 3)


def test_shape_errors_are_clear():
    a = torch.zeros(4, 6, 3)
    with pytest.raises(InputError, match="shapes differ"):
        losses.ssim(a, torch.zeros(4, 5, 3))
    with pytest.raises(InputError, match="weight shape"):
        losses.masked_l1(a, a, torch.ones(5, 6))
    with pytest.raises(InputError, match=r"\(H, W, 3\)"):
        losses.ssim(torch.zeros(4, 6), torch.zeros(4, 6))


def test_psnr_torch_known_mse():
    a = torch.zeros(8, 8, 3)
    assert losses.psnr_torch(a, a + 0.1) == pytest.approx(20.0, abs=1e-5)
    assert losses.psnr_torch(a, a) == float("inf")


def test_the_device_loss_is_the_torch_loss_without_value_checks():
    """``stg_loss_device`` (the CUDA training path) computes ``stg_loss_torch`` on a batch of
    views with per-pixel weights, and refuses mismatched shapes on the host."""
    g = torch.Generator().manual_seed(3)
    render, target = torch.rand(2, 12, 10, 3, generator=g), torch.rand(2, 12, 10, 3, generator=g)
    weight = 1.0 + 4.0 * (torch.rand(2, 12, 10, generator=g) > 0.5).float()
    assert torch.equal(losses.stg_loss_device(render, target, weight), losses.stg_loss_torch(render, target, weight))
    assert torch.equal(losses.stg_loss_device(render, target), losses.stg_loss_torch(render, target))
    with pytest.raises(InputError, match="one shape"):
        losses.stg_loss_device(render, target[:1])
