"""The gsplat backend's adapter (fixer4d/render/gsplat_backend.py), with and without CUDA.

Without CUDA a stand-in ``gsplat`` module records what the adapter passes to
``gsplat.rasterization`` and answers with outputs of the documented shapes, so the call is
checked against gsplat's documented API: one camera; world-to-camera ``viewmats`` in OpenCV axes
and pixel ``Ks``; activated scales and opacities; quaternions wxyz; post-activation colours with
``sh_degree`` None; ``packed=False``; "RGB+ED"; a (1, 3) background. The outputs must come back
as fixer4d's RenderOutput, gradients included. With CUDA and gsplat installed, the parity test
renders one snapshot with "gsplat" and "cpu" and compares images and gradients.

The gsplat row of the parity table in docs/render.md (the rendering contract).
"""
from __future__ import annotations

import importlib.util
import math
import sys
import types

import numpy as np
import pytest
import torch

from fixer4d.errors import BackendUnavailable
from fixer4d.model.spacetime import ModelConfig, SpacetimeGaussians
from fixer4d.render import gsplat_backend
from fixer4d.render.api import render
from fixer4d.render.constants import LOWPASS_2D, NEAR_PLANE

from .scenes import FIELDS, front_camera, leaf, loss_weights, random_snapshot

WIDTH, HEIGHT = 20, 14
BACKGROUND = (0.2, 0.4, 0.6)
# The stand-in's image: background + GAIN * (sum of the projected x coordinates) in every colour
# channel, and this expected depth everywhere; so dL/dmeans2d of rgb.sum() is known exactly.
GAIN = 1e-3
EXPECTED_DEPTH = 2.5
ALPHA = 0.5


def _stand_in(calls: list[dict], per_axis_radii: bool) -> types.ModuleType:
    """A ``gsplat`` module whose ``rasterization`` has gsplat's documented parameters (a keyword
    gsplat does not know fails), records them, projects the means with the given viewmats and
    Ks (so means2d is differentiable in the means) and returns the documented shapes: colours
    (C, H, W, D + 1) for "RGB+ED", alphas (C, H, W, 1), meta radii (C, N) or (C, N, 2) int32 and
    means2d (C, N, 2)."""

    def rasterization(means, quats, scales, opacities, colors, viewmats, Ks, width, height, near_plane=0.01,
                      far_plane=1e10, radius_clip=0.0, eps2d=0.3, sh_degree=None, packed=True, tile_size=16,
                      backgrounds=None, render_mode="RGB", sparse_grad=False, absgrad=False,
                      rasterize_mode="classic", channel_chunk=32, distributed=False, camera_model="pinhole",
                      segmented=False, covars=None):
        calls.append(dict(locals()))
        cams, n = viewmats.shape[0], means.shape[0]
        in_camera = means @ viewmats[0, :3, :3].T + viewmats[0, :3, 3]
        pixels = in_camera @ Ks[0].T
        means2d = (pixels[:, :2] / pixels[:, 2:3])[None]  # (C, N, 2)
        shift = GAIN * means2d[..., 0].sum(-1)  # (C,)
        channels = colors.shape[-1]
        rgb = backgrounds[:, None, None, :].expand(cams, height, width, channels) + shift[:, None, None, None]
        depth = torch.full((cams, height, width, 1), EXPECTED_DEPTH)
        alphas = torch.full((cams, height, width, 1), ALPHA)
        radii = torch.arange(2 * n, dtype=torch.int32).reshape(1, n, 2)
        radii[:, 0] = 0  # culled: zero on both axes
        if not per_axis_radii:
            radii = radii[..., 1]
        return torch.cat([rgb, depth], -1), alphas, {"radii": radii, "means2d": means2d, "depths": in_camera[None, :, 2]}

    module = types.ModuleType("gsplat")
    module.rasterization = rasterization
    return module


def _model() -> SpacetimeGaussians:
    """Five static Gaussians in front of the camera whose raw Parameters differ from their
    activated values (log scales vs scales, logits vs opacities) and whose quaternions are
    unnormalized with four distinct components."""
    model = SpacetimeGaussians(ModelConfig(motion_degree=0, rotation_velocity=False, temporal_opacity=False), 5)
    with torch.no_grad():
        model.means.copy_(torch.tensor([[0.0, 0.0, 0.0], [0.3, -0.2, 0.1], [-0.4, 0.25, -0.3],
                                        [0.1, 0.35, 0.4], [-0.2, -0.3, 0.2]]))
        model.log_scales.fill_(math.log(0.1))
        model.quats.copy_(torch.tensor([2.0, 0.3, -0.1, 0.5]).expand(5, 4))
        model.opacity_logits.copy_(torch.tensor([0.5, -1.0, 1.5, 0.0, 2.0]))
        model.colors.uniform_(-0.5, 0.5)
    return model


@pytest.fixture
def stand_in(monkeypatch):
    """Install the stand-in gsplat and let CPU tensors through the adapter's CUDA checks."""
    calls: list[dict] = []

    def install(per_axis_radii: bool = True) -> list[dict]:
        monkeypatch.setitem(sys.modules, "gsplat", _stand_in(calls, per_axis_radii))
        monkeypatch.setattr(gsplat_backend, "unavailable_reason", lambda: None)
        monkeypatch.setattr(gsplat_backend, "_device_problem", lambda device: None)
        return calls

    return install


@pytest.mark.parametrize("per_axis_radii", [True, False])
def test_the_adapter_calls_gsplat_as_documented(stand_in, per_axis_radii):
    calls = stand_in(per_axis_radii)
    model, cam = _model(), front_camera(WIDTH, HEIGHT)
    out = render(model.at(0.5), cam, background=BACKGROUND, backend="gsplat")
    (call,) = calls
    n = model.num_gaussians
    # activated values, wxyz quaternions as they are (gsplat normalizes them itself)
    torch.testing.assert_close(call["means"], model.means.detach(), rtol=0, atol=0)
    torch.testing.assert_close(call["quats"], model.quats.detach(), rtol=0, atol=0)
    assert call["quats"][0].tolist() == pytest.approx([2.0, 0.3, -0.1, 0.5])  # w first
    torch.testing.assert_close(call["scales"], torch.exp(model.log_scales.detach()), rtol=0, atol=0)
    torch.testing.assert_close(call["opacities"], torch.sigmoid(model.opacity_logits.detach()), rtol=0, atol=0)
    assert call["colors"].shape == (n, 3) and call["sh_degree"] is None  # post-activation RGB, not SH
    assert bool(((call["colors"] >= 0) & (call["colors"] <= 1)).all())
    for name in ("means", "quats", "scales", "opacities", "colors"):
        assert call[name].dtype == torch.float32
    # one camera: world-to-camera in OpenCV axes (x right, y down, z forward), pixel intrinsics
    assert call["viewmats"].shape == (1, 4, 4) and call["Ks"].shape == (1, 3, 3)
    np.testing.assert_allclose(call["viewmats"][0].numpy(), cam.w2c, atol=1e-6)
    np.testing.assert_allclose(call["Ks"][0].numpy(), cam.K, atol=1e-6)
    centre = call["viewmats"][0] @ torch.tensor([*cam.center, 1.0], dtype=torch.float32)
    np.testing.assert_allclose(centre.numpy(), [0, 0, 0, 1], atol=1e-5)  # the camera sits at the origin
    ahead = call["viewmats"][0] @ torch.tensor([*(cam.center + cam.forward), 1.0], dtype=torch.float32)
    assert ahead[2] > 0.99  # z forward
    assert (call["width"], call["height"]) == (WIDTH, HEIGHT)
    assert isinstance(call["width"], int) and isinstance(call["height"], int)
    # fixer4d's thresholds and the layout the conversion below relies on
    assert call["near_plane"] == NEAR_PLANE and call["eps2d"] == LOWPASS_2D and call["far_plane"] == 1e10
    assert call["render_mode"] == "RGB+ED" and call["packed"] is False and call["rasterize_mode"] == "classic"
    assert call["covars"] is None and call["distributed"] is False and call["camera_model"] == "pinhole"
    assert call["backgrounds"].shape == (1, 3)
    np.testing.assert_allclose(call["backgrounds"][0].numpy(), BACKGROUND, atol=1e-7)

    # gsplat's outputs as fixer4d's RenderOutput
    assert out.backend == "gsplat" and out.n_fragments == -1
    assert out.rgb.shape == (HEIGHT, WIDTH, 3) and out.alpha.shape == (HEIGHT, WIDTH)
    assert out.depth.shape == (HEIGHT, WIDTH) and out.radii.shape == (n,) and out.means2d.shape == (n, 2)
    assert out.radii.dtype == torch.int32
    expected_radii = np.arange(2 * n).reshape(n, 2)
    expected_radii[0] = 0
    np.testing.assert_array_equal(out.radii.numpy(), expected_radii.max(1) if per_axis_radii else expected_radii[:, 1])
    torch.testing.assert_close(out.alpha, torch.full((HEIGHT, WIDTH), ALPHA))
    torch.testing.assert_close(out.depth, torch.full((HEIGHT, WIDTH), EXPECTED_DEPTH))
    uv, _ = cam.project(model.means.detach().double().numpy())  # the projection of a world-to-camera view
    np.testing.assert_allclose(out.means2d.numpy(), uv, atol=1e-3)
    shift = GAIN * out.means2d[:, 0].sum()
    torch.testing.assert_close(out.rgb[3, 4], torch.tensor(BACKGROUND) + shift)


def test_means2d_receives_its_gradient_and_the_snapshot_its_own(stand_in):
    """RenderOutput.means2d.grad is dL/dmeans2d after backward (the trainer's densification
    statistics), though gsplat rasterizes from its own (1, N, 2) tensor; the gradient reaches
    the model's Parameters through gsplat's graph."""
    stand_in()
    model = _model()
    out = render(model.at(0.5), front_camera(WIDTH, HEIGHT), background=BACKGROUND, backend="gsplat")
    out.rgb.sum().backward()
    expected = torch.zeros(model.num_gaussians, 2)
    expected[:, 0] = GAIN * HEIGHT * WIDTH * 3
    torch.testing.assert_close(out.means2d.grad, expected)
    assert model.means.grad is not None and bool(model.means.grad.abs().sum() > 0)


def test_cpu_tensors_are_refused_by_the_cuda_backend(monkeypatch):
    """The adapter's own device check: with gsplat importable, CPU tensors still fail clearly."""
    monkeypatch.setitem(sys.modules, "gsplat", _stand_in([], True))
    monkeypatch.setattr(gsplat_backend, "unavailable_reason", lambda: None)
    with pytest.raises(BackendUnavailable, match="needs CUDA tensors"):
        render(_model().at(0.5), front_camera(WIDTH, HEIGHT), backend="gsplat")


@pytest.fixture
def cuda_with_gsplat(monkeypatch):
    """A machine that reports CUDA and has a ``gsplat`` package, whose ``gsplat.cuda._backend``
    the test sets (a module, or None: its import fails); the extension check is asked afresh."""
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setitem(sys.modules, "gsplat", types.ModuleType("gsplat"))
    monkeypatch.setitem(sys.modules, "gsplat.cuda", types.ModuleType("gsplat.cuda"))
    gsplat_backend.extension_problem.cache_clear()

    def backend(module: types.ModuleType | None) -> None:
        monkeypatch.setitem(sys.modules, "gsplat.cuda._backend", module)

    yield backend
    gsplat_backend.extension_problem.cache_clear()


def _backend_module(extension) -> types.ModuleType:
    module = types.ModuleType("gsplat.cuda._backend")
    module._C = extension
    return module


def test_gsplat_whose_extension_loads_is_available(cuda_with_gsplat):
    cuda_with_gsplat(_backend_module(object()))
    assert gsplat_backend.unavailable_reason() is None


@pytest.mark.parametrize("module, words", [
    (_backend_module(None), "no CUDA toolkit to build it"),  # gsplat's own answer without nvcc: _C = None
    (None, "failed to build or load"),  # the extension's import raised (a failed build)
])
def test_gsplat_without_its_cuda_extension_is_unavailable_and_auto_trains_on_the_cpu(cuda_with_gsplat, module,
                                                                                       words):
    from fixer4d.train.device import training_device

    cuda_with_gsplat(module)
    assert words in gsplat_backend.unavailable_reason()
    assert training_device("auto", "auto") == torch.device("cpu")
    with pytest.raises(BackendUnavailable, match=words):
        training_device("cuda", "auto")


@pytest.mark.skipif(torch.cuda.is_available(), reason="checks the answer on a machine without CUDA")
def test_without_cuda_the_backend_says_why():
    with pytest.raises(BackendUnavailable, match="CUDA is not available"):
        render(_model().at(0.5), front_camera(WIDTH, HEIGHT), backend="gsplat")


# ---------------------------------------------------------------------------- parity on CUDA
# gsplat cuts each splat at its tile box, the CPU kernels per pixel at 3 sigma: beyond the
# ellipse a splat still adds alpha <= opacity * exp(-4.5) ~ 0.011 in gsplat, so a few pixels
# where such fringes overlap differ by a few hundredths, and the images as a whole by little.
PARITY_PSNR_DB = 35.0
PARITY_MAX_ABS = 0.06
PARITY_MEANS2D_PX = 1e-3  # float32 projection of the same means on either side
PARITY_GRAD_COSINE = 0.95  # per field: the fringe's share of each gradient is small
HAS_GSPLAT = importlib.util.find_spec("gsplat") is not None


@pytest.mark.skipif(not torch.cuda.is_available() or not HAS_GSPLAT,
                    reason="needs CUDA and gsplat: the gsplat backend against the CPU kernel")
def test_gsplat_renders_and_differentiates_like_the_cpu_backend():
    snap = random_snapshot(300, seed=4, dtype=torch.float32)
    cam = front_camera(64, 48)
    w_rgb, w_alpha, _ = loss_weights(cam.height, cam.width, torch.float32, seed=5)
    res = {}
    for backend, device in (("cpu", "cpu"), ("gsplat", "cuda")):
        s = leaf(snap.to(device=device))
        out = render(s, cam, background=BACKGROUND, backend=backend)
        # depth is compared where both are opaque: its normalization differs where alpha ~ 0
        ((out.rgb * w_rgb.to(device)).sum() + (out.alpha * w_alpha.to(device)).sum()).backward()
        res[backend] = (out, s)
    (cpu, s_cpu), (gpu, s_gpu) = res["cpu"], res["gsplat"]
    rgb_cpu, rgb_gpu = cpu.rgb.detach(), gpu.rgb.detach().cpu()
    mse = float(((rgb_cpu - rgb_gpu) ** 2).mean())
    assert 10 * math.log10(1.0 / max(mse, 1e-20)) >= PARITY_PSNR_DB
    assert float((rgb_cpu - rgb_gpu).abs().max()) <= PARITY_MAX_ABS
    assert float((cpu.alpha.detach() - gpu.alpha.detach().cpu()).abs().max()) <= PARITY_MAX_ABS
    opaque = (cpu.alpha.detach() > 0.5) & (gpu.alpha.detach().cpu() > 0.5)
    depth_gap = (cpu.depth.detach() - gpu.depth.detach().cpu()).abs()[opaque]
    assert float(depth_gap.max()) <= PARITY_MAX_ABS * float(cpu.depth.detach()[opaque].max())
    drawn = (cpu.radii > 0) & (gpu.radii.cpu() > 0)
    gap = (cpu.means2d.detach() - gpu.means2d.detach().cpu()).abs()[drawn]
    assert float(gap.max()) <= PARITY_MEANS2D_PX
    grads = {f: (getattr(s_cpu, f).grad, getattr(s_gpu, f).grad.cpu()) for f in FIELDS}
    grads["means2d"] = (cpu.means2d.grad, gpu.means2d.grad.cpu())
    for name, (a, b) in grads.items():
        cosine = float(torch.nn.functional.cosine_similarity(a.reshape(1, -1), b.reshape(1, -1)))
        assert cosine >= PARITY_GRAD_COSINE, (name, cosine)
