"""One regression test per class of hard input (docs/numerics.md): without the entry point's
validation or guard each gives a silent wrong value, NaN, or a foreign exception."""
from __future__ import annotations

import json
import warnings

import numpy as np
import pytest
import torch

from fixer4d.errors import InputError
from fixer4d.eval import metrics as M
from fixer4d.geometry.camera import Camera
from fixer4d.geometry.trajectory import interpolate_pair, save_nerfstudio, scene_trajectories, Trajectory
from fixer4d.init.fusion import consistent_points
from fixer4d.model.io import load_npz, save_npz
from fixer4d.model.snapshot import Snapshot
from fixer4d.model.spacetime import ModelConfig, SpacetimeGaussians
from fixer4d.render import render
from fixer4d.train import losses


def _cam(**kw) -> Camera:
    return Camera.look_at([0.0, 0.0, -3.0], [0.0, 0.0, 0.0], width=32, height=24, **kw)


def _snapshot(n=3, dtype=torch.float32, **fields) -> Snapshot:
    g = torch.Generator().manual_seed(0)
    base = {"means": torch.randn(n, 3, generator=g, dtype=dtype) * 0.3,
            "quats": torch.tensor([[1.0, 0.0, 0.0, 0.0]] * n, dtype=dtype),
            "scales": torch.full((n, 3), 0.1, dtype=dtype), "opacities": torch.full((n,), 0.8, dtype=dtype),
            "colors": torch.full((n, 3), 0.5, dtype=dtype)}
    base.update({k: torch.as_tensor(v, dtype=dtype) for k, v in fields.items()})
    return Snapshot(**{k: v.clone().requires_grad_(True) for k, v in base.items()})


def _grads_finite(snap: Snapshot, out) -> bool:
    (out.rgb.sum() + out.depth.sum() + out.alpha.sum()).backward()
    return all(torch.isfinite(t.grad).all() for t in (snap.means, snap.quats, snap.scales, snap.opacities, snap.colors)
               if t.grad is not None)


# ---- cameras ---------------------------------------------------------------------------------
def test_camera_refuses_skew_lower_entries_mirrors_and_projective_rows():
    base = _cam()
    K = base.K.copy()
    K[0, 1] = 5.0  # skew: Camera.project would use it, the rasterizers would not (px apart)
    with pytest.raises(InputError, match="skew"):
        Camera(K, base.c2w, 32, 24)
    K = base.K.copy()
    K[1, 0] = 3.0
    with pytest.raises(InputError, match="upper-triangular"):
        Camera(K, base.c2w, 32, 24)
    mirror = base.c2w.copy()
    mirror[:3, 0] *= -1.0  # det -1
    with pytest.raises(InputError, match="mirror"):
        Camera(base.K, mirror, 32, 24)
    projective = base.c2w.copy()
    projective[3, 2] = 0.5
    with pytest.raises(InputError, match="bottom row"):
        Camera(base.K, projective, 32, 24)


def test_camera_normalises_k22_with_a_warning_and_projects_like_the_renderer():
    base = _cam()
    with pytest.warns(UserWarning, match=r"K\[2,2\]"):
        cam = Camera(base.K * 2.0, base.c2w, 32, 24)
    assert cam.K[2, 2] == 1.0 and cam.fx == base.fx
    snap = _snapshot()
    uv, _ = cam.project(snap.means.detach().numpy())
    out = render(snap, cam, backend="reference")
    np.testing.assert_allclose(uv, out.means2d.detach().numpy(), atol=1e-3)


# ---- metrics ---------------------------------------------------------------------------------
def test_metrics_refuse_8bit_tiny_and_empty_images_and_huge_values():
    a = np.full((16, 16, 3), 100, np.uint8)
    with pytest.raises(InputError, match="uint8"):
        M.psnr(a, a + 1)  # read as [0, 1], one level apart would score 0 dB
    small = np.zeros((5, 5, 3), np.float32)
    with pytest.raises(InputError, match="at least 7x7"):
        M.dssim1(small, small)  # not scikit-image's ValueError
    empty = np.zeros((0, 0, 3), np.float32)
    with pytest.raises(InputError, match="too small"):
        M.psnr(empty, empty)  # not NaN
    huge = np.full((16, 16, 3), 1e30, np.float32)
    with pytest.raises(InputError, match="values up to"):
        M.dssim1(huge, huge * 0.5)  # not a NaN DSSIM


def test_psnr_torch_refuses_mismatched_shapes():
    with pytest.raises(InputError, match="one shape"):
        losses.psnr_torch(torch.zeros(8, 8, 3), torch.zeros(8, 1, 3))  # no silent broadcasting


# ---- losses ----------------------------------------------------------------------------------
@pytest.mark.parametrize("fn", [losses.stg_loss, losses.stg_loss_torch, losses.ssim, losses.l1])
def test_losses_stay_finite_for_large_finite_float32(fn):
    render_ = torch.full((12, 12, 3), 3e19, requires_grad=True)  # x*x overflows float32
    target = torch.zeros(12, 12, 3)
    loss = fn(render_, target)
    loss.backward()
    assert torch.isfinite(loss) and torch.isfinite(render_.grad).all() and loss.dtype == torch.float32


def test_losses_refuse_empty_images_and_negative_weights():
    with pytest.raises(InputError, match="empty"):
        losses.stg_loss(torch.zeros(0, 4, 3), torch.zeros(0, 4, 3))  # not NaN
    a, b = torch.rand(8, 8, 3), torch.rand(8, 8, 3)
    with pytest.raises(InputError, match=">= 0"):
        losses.stg_loss(a, b, -torch.ones(8, 8))  # not a negative loss


# ---- rendering -------------------------------------------------------------------------------
@pytest.mark.parametrize("backend", ["cpu", "reference"])
def test_non_finite_background_is_an_input_error(backend):
    with pytest.raises(InputError, match="background must be finite"):
        render(_snapshot(), _cam(), background=(float("nan"), 0.0, 0.0), backend=backend)


@pytest.mark.parametrize("backend", ["cpu", "reference"])
@pytest.mark.parametrize("field,value", [("means", [[3e38, 0, 0], [0, 0, 0], [0, 0, 1]]),
                                         ("means", [[0, 0, 3e38], [0, 0, 0], [0, 0, 1]]),
                                         ("colors", [[3e38] * 3, [0.5] * 3, [0.5] * 3]),
                                         ("scales", [[1e30] * 3, [0.1] * 3, [0.1] * 3])])
def test_extreme_finite_gaussians_give_finite_gradients(backend, field, value):
    snap = _snapshot(**{field: value})
    out = render(snap, _cam(), backend=backend)
    assert torch.isfinite(out.rgb).all() and _grads_finite(snap, out)


@pytest.mark.parametrize("fields", [{"scales": [[1e12] * 3, [0.1] * 3, [0.1] * 3]},
                                    {"quats": [[1e25, 0, 0, 1e25], [1, 0, 0, 0], [1, 0, 0, 0]],
                                     "scales": [[0.6, 0.02, 0.02], [0.1] * 3, [0.1] * 3]}])
def test_float32_matches_the_float64_oracle_on_extreme_scales_and_quaternions(fields):
    snap64 = _snapshot(dtype=torch.float64, **fields)
    ref = render(snap64, _cam(), backend="reference")
    fast = render(snap64, _cam(), backend="cpu")  # cast to float32 inside
    np.testing.assert_array_equal(ref.radii.numpy() == 0, fast.radii.numpy() == 0)
    np.testing.assert_allclose(fast.rgb.detach().numpy(), ref.rgb.detach().numpy(), atol=1e-4)


def test_kernel_and_oracle_cull_alike_on_degenerate_splats():
    from fixer4d.render.project import project_gaussians
    from fixer4d.render.project_cpu import project_gaussians_cpu

    # T = J W R S entries above T_ENTRY_MAX: culled by both (float32 radii ~5e8 px differ by round-off)
    snap = _snapshot(means=[[-1e4, -1e-3, 10.0]], quats=[[-1e-3, -10.0, 1e15, 1.0]], scales=[[0.1, 1e4, 1e8]],
                     opacities=[0.5], colors=[[0.5] * 3], n=1)
    a = project_gaussians(snap, _cam()).radii
    b = project_gaussians_cpu(snap, _cam()).radii
    assert a.tolist() == b.tolist() == [0]


# ---- models and files ------------------------------------------------------------------------
def test_from_points_refuses_coordinates_beyond_float32():
    pts = np.array([[0.0, 0.0, 0.0], [1e39, 0.0, 0.0], [0.0, 1.0, 0.0]])
    with pytest.raises(InputError, match="float32"):
        SpacetimeGaussians.from_points(pts, np.full((3, 3), 0.5), np.zeros(3))


def test_npz_with_string_arrays_is_an_input_error(tmp_path):
    m = SpacetimeGaussians.from_points(np.random.default_rng(0).random((4, 3)), np.full((4, 3), 0.5), np.zeros(4),
                                       ModelConfig(motion_degree=0, rotation_velocity=False, temporal_opacity=False))
    path = save_npz(m, tmp_path / "m.npz")
    with np.load(path) as z:
        arrays = {k: z[k] for k in z.files}
    arrays["means"] = np.array([["a", "b", "c"]] * 4)
    np.savez(tmp_path / "bad.npz", **arrays)
    with pytest.raises(InputError, match="not numeric"):
        load_npz(tmp_path / "bad.npz")  # not a raw TypeError


def test_at_infinite_time_names_t():
    m = SpacetimeGaussians.from_points(np.random.default_rng(0).random((4, 3)), np.full((4, 3), 0.5), np.zeros(4))
    with pytest.raises(InputError, match=r"at\(t\)"):
        m.at(float("inf"))  # names t, not a 'diverged' model


# ---- fusion and trajectories -----------------------------------------------------------------
def test_fusion_refuses_a_nan_depth_tolerance():
    cams = [_cam(name="a"), Camera.look_at([0.5, 0.0, -3.0], [0.0, 0.0, 0.0], width=32, height=24, name="b")]
    images = [np.full((24, 32, 3), 0.5, np.float32)] * 2
    depths = [np.full((24, 32), 3.0, np.float32)] * 2
    with pytest.raises(InputError, match="depth_tol"):
        consistent_points(images, depths, cams, depth_tol=float("nan"))  # not a silent 0 points


def test_scene_trajectories_refuse_a_camera_listed_twice():
    a, b = _cam(name="a"), Camera.look_at([1.0, 0.0, -3.0], [0.0, 0.0, 0.0], width=32, height=24, name="b")
    with pytest.raises(InputError, match="listed twice"):
        scene_trajectories([a, b, a], 4)


def test_nerfstudio_export_warns_about_what_it_cannot_hold(tmp_path):
    base = _cam()
    K = base.K.copy()
    K[0, 0] *= 1.2  # non-square pixels
    K[0, 2] += 3.0  # off-centre principal point
    odd = Camera(K, base.c2w, 32, 24, "odd")
    traj = Trajectory("t", [odd, odd], np.array([0.0, 1.0]))
    with pytest.warns(UserWarning, match="non-square pixels.*off-centre principal point"):
        save_nerfstudio(traj, tmp_path / "path.json")
    plain = Trajectory("p", interpolate_pair(base, Camera.look_at([1.0, 0.0, -3.0], [0, 0, 0], width=32, height=24),
                                             [0.0, 1.0]), np.array([0.0, 1.0]))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        save_nerfstudio(plain, tmp_path / "plain.json")  # square, centred: nothing to warn about
    assert json.loads((tmp_path / "plain.json").read_text())["render_width"] == 32
