"""Property tests of the public entry points (docs/numerics.md): finite input -> finite output or
InputError (never NaN, never a foreign exception); float32 and the float64 oracle agree where
both run. Bounded examples: the whole file runs in seconds."""
from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from fixer4d.errors import InputError
from numerics_finite import finite
from fixer4d.eval import metrics as M
from fixer4d.geometry import Camera, rig_extent
from fixer4d.geometry.trajectory import Trajectory, save_nerfstudio, scene_trajectories
from fixer4d.init import FrameCloud, merge_clouds
from fixer4d.init.fusion import consistent_points, filter_cloud
from fixer4d.model import ModelConfig, Snapshot, SpacetimeGaussians, load_model, save_model
from fixer4d.render import render, resolve_backend
from fixer4d.scene import check_frame_range, parse_frame_range
from fixer4d.train import losses

SETTINGS = settings(max_examples=15, deadline=None, derandomize=True,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                           HealthCheck.function_scoped_fixture])

F32 = st.floats(allow_nan=False, allow_infinity=False, width=32)
UNIT = st.floats(min_value=0.0, max_value=1.0, allow_nan=False, width=32)
# magnitudes spanning float32: tiny, unit-order and near overflow, either sign
MAG = st.sampled_from([0.0, 1e-30, 1e-6, 0.1, 1.0, 7.0, 1e4, 1e12, 1e20, 1e30, 3e38])
SIGNED_MAG = st.builds(lambda m, s: m * s, MAG, st.sampled_from([-1.0, 1.0]))


def _image(h, w, dtype=np.float32, elements=F32):
    return hnp.arrays(dtype, (h, w, 3), elements=elements)


@st.composite
def image_pairs(draw, max_side=10):
    h, w = draw(st.integers(0, max_side)), draw(st.integers(0, max_side))
    kind = draw(st.sampled_from(["f32", "f64", "u8", "unit"]))
    if kind == "u8":
        return draw(_image(h, w, np.uint8, st.integers(0, 255))), draw(_image(h, w, np.uint8, st.integers(0, 255)))
    el = UNIT if kind == "unit" else F32
    dt = np.float64 if kind == "f64" else np.float32
    return draw(_image(h, w, dt, el)), draw(_image(h, w, dt, el))


# ---- geometry --------------------------------------------------------------------------------
@st.composite
def camera_args(draw):
    fx, fy = draw(SIGNED_MAG), draw(SIGNED_MAG)
    K = np.array([[fx, draw(st.sampled_from([0.0, 0.0, 1e-12, 2.0])), draw(SIGNED_MAG)],
                  [draw(st.sampled_from([0.0, 0.0, 1.0])), fy, draw(SIGNED_MAG)],
                  [0.0, 0.0, draw(st.sampled_from([1.0, 1.0, 2.0, -1.0, 1e-300]))]])
    q = np.array([draw(st.floats(-1, 1)) for _ in range(4)]) + np.array([1e-3, 0, 0, 0])
    from fixer4d.geometry.quaternion import to_matrix

    R = to_matrix(q / np.linalg.norm(q)) * draw(st.sampled_from([1.0, 1.0, -1.0, 1.5]))
    c2w = np.eye(4)
    c2w[:3, :3] = R
    c2w[:3, 3] = [draw(SIGNED_MAG) for _ in range(3)]
    c2w[3, 2] = draw(st.sampled_from([0.0, 0.0, 0.5]))
    return K, c2w, draw(st.sampled_from([1, 7, 32, 0, 2.5])), draw(st.sampled_from([1, 5, 24]))


@SETTINGS
@given(camera_args())
def test_camera_validates_or_projects_like_the_renderer(args):
    K, c2w, w, h = args
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        try:
            cam = Camera(K, c2w, w, h, "p")
        except InputError:
            return
    assert np.isfinite(cam.K).all() and np.isfinite(cam.w2c).all() and cam.K[2, 2] == 1.0
    assert cam.K[0, 1] == 0.0 or abs(cam.K[0, 1]) <= 1e-9 * cam.fx
    p_cam = np.array([[0.1, -0.2, 2.0]])
    p_world = p_cam @ cam.R.T + cam.center
    uv, z = cam.project(p_world)
    # the rasterizers' formula: fx x / z + cx (no skew, no K[2, 2])
    pc = cam.world_to_camera(p_world)
    if np.isfinite(uv).all() and z[0] > 0:
        expect = [cam.fx * pc[0, 0] / pc[0, 2] + cam.cx, cam.fy * pc[0, 1] / pc[0, 2] + cam.cy]
        np.testing.assert_allclose(uv[0], expect, rtol=1e-6, atol=1e-6 * (abs(cam.cx) + abs(cam.cy) + 1))
    assert math.isfinite(rig_extent([cam, cam]))


# ---- metrics ---------------------------------------------------------------------------------
@SETTINGS
@given(image_pairs(), st.sampled_from(["psnr", "dssim1", "dssim2", "ssim_map", "image_metrics"]))
def test_metrics_finite_or_input_error(pair, name):
    a, b = pair
    try:
        out = getattr(M, name)(a, b)
    except InputError:
        return
    if name == "psnr" and out == math.inf:
        assert np.array_equal(a.astype(np.float64), b.astype(np.float64))
        return
    if isinstance(out, dict) and out.get("psnr") == math.inf:
        out = {k: v for k, v in out.items() if k != "psnr"}
    assert finite(out), out


@SETTINGS
@given(image_pairs(), st.data())
def test_masked_and_region_metrics_finite_or_input_error(pair, data):
    a, b = pair
    mask = data.draw(hnp.arrays(np.bool_, a.shape[:2]))
    for fn in (M.masked_psnr, M.region_metrics):
        try:
            out = fn(a, b, mask)
        except InputError:
            continue
        values = [out] if not isinstance(out, dict) else list(out.values())
        assert all(v is None or v == math.inf or math.isfinite(v) for v in values), out


# ---- losses ----------------------------------------------------------------------------------
@st.composite
def loss_inputs(draw):
    h, w = draw(st.integers(0, 9)), draw(st.integers(0, 9))
    el = draw(st.sampled_from([UNIT, F32]))
    a = torch.from_numpy(draw(_image(h, w, np.float32, el))).requires_grad_(True)
    b = torch.from_numpy(draw(_image(h, w, np.float32, el)))
    weight = None
    if draw(st.booleans()):
        weight = torch.from_numpy(draw(hnp.arrays(np.float32, (h, w), elements=st.sampled_from(
            [0.0, 0.5, 1.0, 2.0, -1.0, 1e30]))))
    return a, b, weight


@SETTINGS
@given(loss_inputs(), st.sampled_from(["stg_loss", "stg_loss_torch", "ssim", "dssim", "masked_l1", "l1"]))
def test_losses_finite_with_finite_gradients_or_input_error(inputs, name):
    a, b, weight = inputs
    fn = getattr(losses, name)
    try:
        loss = fn(a, b) if name == "l1" else fn(a, b, weight)
    except InputError:
        return
    loss.backward()
    assert torch.isfinite(loss) and torch.isfinite(a.grad).all(), (loss, name)


@SETTINGS
@given(loss_inputs())
def test_fused_and_torch_losses_agree_on_valid_images(inputs):
    a, b, _ = inputs
    assume(a.numel() > 0 and float(a.detach().abs().max()) <= 1.0 and float(b.abs().max()) <= 1.0)
    fused = losses.stg_loss(a, b)
    ref = losses.stg_loss_torch(a.detach().double(), b.double())
    assert float(fused.detach()) == pytest.approx(float(ref), rel=1e-4, abs=1e-5)


@SETTINGS
@given(image_pairs())
def test_psnr_torch_finite_or_input_error_and_matches_numpy(pair):
    a, b = pair
    assume(a.dtype != np.uint8)
    try:
        value = losses.psnr_torch(torch.from_numpy(a), torch.from_numpy(b))
    except InputError:
        return
    assert value == math.inf or math.isfinite(value)
    if a.size and np.abs(a).max() <= 1 and np.abs(b).max() <= 1:
        assert value == pytest.approx(M.psnr(a, b), rel=1e-12)


# ---- rendering -------------------------------------------------------------------------------
@st.composite
def snapshots(draw, dtype=torch.float32, n_max=4):
    n = draw(st.integers(0, n_max))

    def field(shape, el):
        return torch.tensor(np.array([draw(el) for _ in range(int(np.prod(shape)))], np.float64).reshape(shape),
                            dtype=dtype)

    near = st.floats(-1.5, 1.5)
    means = field((n, 3), st.one_of(near, near, SIGNED_MAG))
    quats = field((n, 4), st.one_of(st.floats(-1, 1), SIGNED_MAG))
    scales = field((n, 3), st.one_of(st.floats(1e-4, 0.5), MAG))
    opac = field((n,), st.one_of(UNIT, UNIT, st.sampled_from([-0.5, 1.5])))
    colors = field((n, 3), st.one_of(UNIT, UNIT, SIGNED_MAG))
    return Snapshot(means, quats, scales, opac, colors)


_CAM = Camera.look_at([0.0, 0.0, -3.0], [0.0, 0.0, 0.0], width=16, height=12)


@SETTINGS
@given(snapshots(), st.sampled_from(["cpu", "reference"]),
       st.sampled_from([(0.0, 0.0, 0.0), (1.0, 1.0, 1.0), (3e38, 0.0, 0.0), (float("nan"), 0.0, 0.0)]))
def test_render_finite_image_and_gradients_or_input_error(snap, backend, background):
    leaves = [t.clone().requires_grad_(True) for t in (snap.means, snap.quats, snap.scales, snap.opacities, snap.colors)]
    snap = Snapshot(*leaves)
    try:
        out = render(snap, _CAM, background=background, backend=backend)
    except InputError:
        return
    assert finite(out.rgb) and finite(out.alpha) and finite(out.depth)
    (out.rgb.sum() + out.alpha.sum() + out.depth.sum()).backward()
    assert all(t.grad is None or finite(t.grad) for t in leaves)


@SETTINGS
@given(snapshots(dtype=torch.float64))
def test_float32_render_culls_like_the_float64_oracle(snap):
    try:
        ref = render(snap, _CAM, backend="reference")
    except InputError:
        return
    fast = render(snap, _CAM, backend="cpu")
    np.testing.assert_array_equal(ref.radii.numpy() == 0, fast.radii.numpy() == 0)
    if len(snap) == 0 or float(snap.colors.abs().max()) <= 1.0:
        # thresholds (alpha >= 1/255, 3 sigma) may flip for one splat at one pixel in float32
        assert float((fast.rgb.double() - ref.rgb.detach()).abs().max()) <= 0.05


@SETTINGS
@given(st.text(max_size=12))
def test_resolve_backend_names_or_input_error(name):
    try:
        assert resolve_backend(name, torch.device("cpu")) in ("reference", "cpu")
    except InputError:
        assert name != "auto"


# ---- models and files ------------------------------------------------------------------------
@SETTINGS
@given(hnp.arrays(np.float64, st.tuples(st.integers(0, 5), st.just(3)),
                  elements=st.one_of(st.floats(-2, 2), st.sampled_from([1e20, -1e35, 1e39, 1e200]))),
       st.one_of(st.none(), st.sampled_from([0.1, 1e-300, 1e300])), st.floats(-1e7, 1e7))
def test_from_points_and_at_finite_or_input_error(points, t_scale, t):
    n = len(points)
    try:
        model = SpacetimeGaussians.from_points(points, np.full((n, 3), 0.5), np.linspace(0, 1, n), t_scale=t_scale)
    except InputError:
        return
    assert all(torch.isfinite(p).all() for p in model.parameters())
    try:
        snap = model.at(t)
    except InputError:
        assert abs(t) > 1e6
        return
    assert all(finite(getattr(snap, f)) for f in ("means", "quats", "scales", "opacities", "colors"))


@SETTINGS
@given(st.integers(0, 4), st.integers(0, 3), st.booleans(), st.booleans(), st.integers(0, 2),
       st.sampled_from([".npz", ".ply"]))
def test_model_files_round_trip_finite(n, motion, rot, temporal, sh, suffix):
    import tempfile
    from pathlib import Path

    cfg = ModelConfig(motion_degree=motion, rotation_velocity=rot, temporal_opacity=temporal, sh_degree=sh)
    rng = np.random.default_rng(n)
    model = SpacetimeGaussians.from_points(rng.random((n, 3)), rng.random((n, 3)), rng.random(n), cfg)
    with tempfile.TemporaryDirectory() as tmp:
        back = load_model(save_model(model, Path(tmp) / f"m{suffix}"))
    assert back.num_gaussians == n and all(torch.isfinite(p).all() for p in back.parameters())


@SETTINGS
@given(st.lists(hnp.arrays(np.float64, st.tuples(st.integers(0, 4), st.just(3)),
                           elements=st.one_of(st.floats(-5, 5), st.sampled_from([1e39, -1e30]))), max_size=3))
def test_frame_clouds_finite_or_input_error(arrays):
    clouds = []
    for k, pts in enumerate(arrays):
        try:
            clouds.append(FrameCloud(k, k / 3, pts, np.full_like(pts, 0.5)))
        except InputError:
            continue
    points, colors, times = merge_clouds(clouds)
    assert finite((points, colors, times))


@SETTINGS
@given(st.one_of(st.text(max_size=8), st.tuples(st.integers(-3, 30), st.integers(-3, 30)).map(lambda t: f"{t[0]}:{t[1]}")),
       st.one_of(st.none(), st.integers(1, 20)))
def test_frame_ranges_parse_or_input_error(text, num_frames):
    try:
        a, b = parse_frame_range(text, num_frames)
    except InputError:
        return
    assert 0 <= a < b and (num_frames is None or b <= num_frames)
    assert check_frame_range((a, b), num_frames) == (a, b)


# ---- fusion and trajectories -----------------------------------------------------------------
_RIG = [Camera.look_at([x, 0.0, -3.0], [0.0, 0.0, 0.0], width=8, height=6, name=f"c{k}")
        for k, x in enumerate((-1.0, 0.0, 1.0))]


@SETTINGS
@given(st.lists(hnp.arrays(np.float32, (6, 8), elements=st.one_of(st.floats(2.0, 4.0, width=32), F32,
                                                                  st.just(float("nan")))), min_size=3, max_size=3),
       st.one_of(st.floats(allow_nan=True), st.just(0.01)), st.integers(-1, 3))
def test_fusion_finite_or_input_error(depths, depth_tol, min_views):
    images = [np.full((6, 8, 3), 0.5, np.float32)] * 3
    try:
        pts, cols = consistent_points(images, depths, _RIG, min_views=min_views, depth_tol=depth_tol)
        pts, cols = filter_cloud(pts, cols, _RIG)
    except InputError:
        return
    assert finite((pts, cols)) and pts.shape[0] == cols.shape[0]


@SETTINGS
@given(st.lists(st.tuples(st.floats(-5, 5), st.floats(-5, 5)), min_size=1, max_size=4),
       st.integers(0, 5), st.booleans())
def test_scene_trajectories_finite_or_input_error(eyes, frames, repeat_first):
    rig = [Camera.look_at([x, y, -4.0], [0.0, 0.0, 0.0], width=8, height=6, name=f"c{k}")
           for k, (x, y) in enumerate(eyes)]
    if repeat_first:
        rig.append(rig[0])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)
        try:
            trajs = scene_trajectories(rig, frames, amplitude=0.2)
        except InputError:
            return
    assert not repeat_first
    assert all(np.isfinite(c.c2w).all() and np.isfinite(c.K).all() for t in trajs for c in t.cameras)


@SETTINGS
@given(st.floats(0.5, 2.0), st.floats(-3.0, 3.0), st.floats(-3.0, 3.0))
def test_nerfstudio_export_warns_exactly_when_intrinsics_are_lost(aspect, dx, dy):
    import tempfile
    from pathlib import Path

    base = _RIG[0]
    K = base.K.copy()
    K[0, 0] *= aspect
    K[0, 2] += dx
    K[1, 2] += dy
    cam = Camera(K, base.c2w, 8, 6, "x")
    lost = abs(aspect - 1.0) > 1e-6 or abs(dx) > 1e-6 * 8 or abs(dy) > 1e-6 * 6
    with tempfile.TemporaryDirectory() as tmp, warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        save_nerfstudio(Trajectory("t", [cam, cam], np.array([0.0, 1.0])), Path(tmp) / "p.json")
    assert any("nerfstudio" in str(w.message) for w in caught) == lost
