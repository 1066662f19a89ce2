"""render(): analytic profile, conventions, errors, empty scenes, backend selection.

The conventions checked here are stated once in docs/render.md (the rendering contract).
"""
from __future__ import annotations

import importlib

import numpy as np
import pytest
import torch

from fixer4d.errors import BackendUnavailable, InputError, NumericalError
from fixer4d.geometry import quaternion as Q
from fixer4d.geometry.camera import Camera
from fixer4d.model.snapshot import Snapshot
from fixer4d.render import gsplat_backend
from fixer4d.render.api import render, resolve_backend
from fixer4d.render.constants import ALPHA_MIN, LOWPASS_2D, SIGMA_EXTENT
from fixer4d.render.project import project_gaussians, quat_to_rotmat

from .scenes import front_camera, leaf, random_snapshot

BACKENDS = ("cpu", "reference")


def _axis_camera(width=33, height=33, f=40.0) -> Camera:
    """Camera at the origin looking down +z (identity pose), centred principal point."""
    K = np.array([[f, 0.0, width / 2.0], [0.0, f, height / 2.0], [0.0, 0.0, 1.0]])
    return Camera(K, np.eye(4), width, height, "axis")


def _one(mean, scale, opacity, quat=(0.3, -0.2, 0.5, 0.1), color=(1.0, 0.5, 0.25), dtype=torch.float32):
    t = lambda v: torch.tensor(v, dtype=dtype)  # noqa: E731
    return Snapshot(t([mean]), t([quat]), t([[scale] * 3]), t([opacity]), t([color]))


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("scale", [0.1, 0.5])
def test_isotropic_gaussian_renders_analytic_profile(backend, scale):
    """alpha(u, v) = o exp(-r^2 / (2 s'^2)) with s'^2 = (f s / z)^2 + 0.3, inside 3 sigma."""
    cam, z, o = _axis_camera(), 5.0, 0.8
    out = render(_one([0.0, 0.0, z], scale, o), cam, backend=backend)
    s2 = (cam.fx * scale / z) ** 2 + LOWPASS_2D
    centres = cam.pixel_centers()
    r2 = ((centres - np.array([cam.cx, cam.cy])) ** 2).sum(-1)
    expect = o * np.exp(-0.5 * r2 / s2)
    expect[(r2 > SIGMA_EXTENT ** 2 * s2) | (expect < ALPHA_MIN)] = 0.0
    np.testing.assert_allclose(out.alpha.detach().numpy(), expect, atol=2e-6)
    np.testing.assert_allclose(out.rgb.detach().numpy(), expect[..., None] * np.array([1.0, 0.5, 0.25]), atol=2e-6)
    depth = out.depth.detach().numpy()
    np.testing.assert_allclose(depth[expect > 0], z, rtol=1e-5)
    assert (depth[expect == 0] == 0).all()
    assert int(out.radii[0]) == int(np.ceil(SIGMA_EXTENT * np.sqrt(s2)))


@pytest.mark.parametrize("backend", BACKENDS)
def test_pixel_centre_convention(backend):
    """A Gaussian on the ray through pixel (3, 7)'s centre projects to (3.5, 7.5) and peaks there."""
    cam = _axis_camera(12, 10)
    point = cam.backproject(np.array([[3.5, 7.5]]), np.array([4.0]))[0]
    out = render(_one(point.tolist(), 0.02, 0.7), cam, backend=backend)
    np.testing.assert_allclose(out.means2d.detach().numpy()[0], [3.5, 7.5], atol=1e-5)
    alpha = out.alpha.detach().numpy()
    assert np.unravel_index(alpha.argmax(), alpha.shape) == (7, 3)
    assert abs(alpha[7, 3] - 0.7) < 1e-6


def test_quaternion_matches_geometry_floor():
    q = np.random.default_rng(0).normal(size=(20, 4))
    ours = quat_to_rotmat(torch.tensor(q)).numpy()
    for i in range(20):
        np.testing.assert_allclose(ours[i], Q.to_matrix(q[i]), atol=1e-12)
    zero = quat_to_rotmat(torch.zeros(1, 4))
    assert torch.equal(zero[0], torch.eye(3))


def test_zero_quaternion_gradient_is_finite():
    s = leaf(_one([0.0, 0.0, 5.0], 0.2, 0.5, quat=(0.0, 0.0, 0.0, 0.0)))
    s.scales = torch.tensor([[0.3, 0.1, 0.2]], requires_grad=True)
    out = render(s, _axis_camera(), backend="reference")
    out.rgb.sum().backward()
    assert torch.isfinite(s.quats.grad).all()


@pytest.mark.parametrize("backend", BACKENDS)
@pytest.mark.parametrize("field", ["means", "quats", "scales", "opacities", "colors"])
@pytest.mark.parametrize("value", [float("nan"), float("inf"), float("-inf")])
def test_non_finite_input_raises_clear_error(backend, field, value):
    # the check reads each field's min and max (Snapshot.ranges): a NaN or an infinity anywhere,
    # in a SIMD lane or in the tail of a vectorized reduction, must still reach them
    for index in (0, 2, -1):
        snap = random_snapshot(37, dtype=torch.float32)
        getattr(snap, field).view(-1)[index] = value
        with pytest.raises(NumericalError, match=rf"{field} has non-finite values in 1 of 37"):
            render(snap, front_camera(), backend=backend)


@pytest.mark.parametrize("backend", BACKENDS)
def test_empty_scene_gives_background(backend):
    z = lambda *s: torch.zeros(*s, requires_grad=True)  # noqa: E731
    snap = Snapshot(z(0, 3), z(0, 4), z(0, 3), z(0), z(0, 3))
    out = render(snap, front_camera(10, 6), background=(0.1, 0.2, 0.3), backend=backend)
    assert torch.allclose(out.rgb, torch.tensor([0.1, 0.2, 0.3]).expand(6, 10, 3))
    assert (out.alpha == 0).all() and (out.depth == 0).all() and out.n_fragments == 0
    (out.rgb.sum() + out.depth.sum() + out.alpha.sum()).backward()
    assert snap.means.grad is not None and snap.means.grad.shape == (0, 3)


@pytest.mark.parametrize("backend", BACKENDS)
def test_background_and_means2d_grad(backend):
    snap = leaf(random_snapshot(40, seed=4, dtype=torch.float32, scale_range=(0.02, 0.1)))
    cam = front_camera(30, 20)
    out = render(snap, cam, background=torch.tensor([0.0, 1.0, 0.0]), backend=backend)
    empty = out.alpha.detach() == 0
    assert empty.any()
    assert torch.equal(out.rgb.detach()[empty], torch.tensor([0.0, 1.0, 0.0]).expand(int(empty.sum()), 3))
    out.rgb.sum().backward()
    g = out.means2d.grad
    assert g is not None and g.shape == (40, 2)
    drawn = out.radii > 0
    assert (g[~drawn] == 0).all() and g[drawn].abs().sum() > 0
    assert out.rgb.dtype == torch.float32 and out.radii.dtype == torch.int32


def test_culling_radii():
    cam = front_camera(20, 20)
    means = torch.tensor([[0.0, 0.0, 0.0], [0.0, 0.0, -6.0], [0.0, 0.0, -4.0], [80.0, 0.0, 0.0]])
    snap = Snapshot(means, torch.tensor([[1.0, 0, 0, 0]] * 4), torch.full((4, 3), 0.1), torch.full((4,), 0.5),
                    torch.rand(4, 3))
    radii = project_gaussians(snap, cam).radii.tolist()
    assert radii[0] > 0 and radii[1:] == [0, 0, 0]  # in view / behind / at the centre / off-screen


def test_reference_follows_float64():
    out = render(random_snapshot(10, dtype=torch.float64), front_camera(), backend="reference")
    assert out.rgb.dtype == torch.float64
    out = render(random_snapshot(10, dtype=torch.float64), front_camera(), backend="cpu")
    assert out.rgb.dtype == torch.float32


def test_backend_selection_and_errors():
    assert resolve_backend("auto", torch.device("cpu")) == "cpu"
    with pytest.raises(InputError, match="unknown render backend"):
        render(random_snapshot(3, dtype=torch.float32), front_camera(), backend="vulkan")
    with pytest.raises(InputError, match="3 values"):
        render(random_snapshot(3, dtype=torch.float32), front_camera(), background=(1.0, 0.0))


@pytest.mark.skipif(torch.cuda.is_available(), reason="checks the error path on a machine without CUDA")
def test_gsplat_backend_unavailable_is_clear():
    importlib.reload(gsplat_backend)  # importing never fails
    assert "CUDA" in gsplat_backend.unavailable_reason()
    with pytest.raises(BackendUnavailable, match="gsplat"):
        render(random_snapshot(3, dtype=torch.float32), front_camera(), backend="gsplat")
