"""Which pixels of a novel view the train cameras already observe (restore.visibility), and the
restorer's output falling back to the render where it may not act (restore.base.blend_with_render)."""
from __future__ import annotations

import numpy as np
import pytest

from fixer4d.errors import InputError
from fixer4d.geometry.camera import Camera
from fixer4d.restore.base import RestoreResult, blend_with_render
from fixer4d.restore.visibility import TrainView, VisibilityConfig, hole_weight, unobserved_weight

WALL_Z = 5.0
# an occluder between the train camera and the wall: x in [0.3, 0.7], y in [-0.3, 0.3] at z = 2.5;
# from the train camera at x = 1 it shadows the wall at x in [-0.4, 0.4], y in [-0.6, 0.6]
OCC = (0.3, 0.7, -0.3, 0.3, 2.5)


def _camera(x: float) -> Camera:
    return Camera.look_at((x, 0.0, 0.0), (x, 0.0, WALL_Z), width=64, height=48, name=f"x{x}")


def _trace(cam: Camera) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """z-depth (H, W) of the first hit (wall or occluder), the hit points (H, W, 3) and whether
    the occluder was hit (H, W)."""
    u = np.arange(cam.width) + 0.5
    v = np.arange(cam.height) + 0.5
    uu, vv = np.meshgrid(u, v)
    rays_cam = np.stack([(uu - cam.cx) / cam.fx, (vv - cam.cy) / cam.fy, np.ones_like(uu)], axis=-1)
    d = rays_cam @ cam.c2w[:3, :3].T  # world direction per unit of camera z
    c = cam.center
    z_wall = (WALL_Z - c[2]) / d[..., 2]
    x0, x1, y0, y1, zo = OCC
    z_occ = (zo - c[2]) / d[..., 2]
    p_occ = c + d * z_occ[..., None]
    hit_occ = (p_occ[..., 0] >= x0) & (p_occ[..., 0] <= x1) & (p_occ[..., 1] >= y0) & (p_occ[..., 1] <= y1)
    depth = np.where(hit_occ, z_occ, z_wall)
    return depth.astype(np.float32), c + d * depth[..., None], hit_occ


def test_pixels_behind_an_occluder_are_unobserved_and_the_rest_observed():
    novel, train = _camera(0.0), _camera(1.0)
    depth, points, occ = _trace(novel)
    tdepth, _, _ = _trace(train)
    w = unobserved_weight(novel, depth, np.ones_like(depth), [TrainView(train, tdepth, np.ones_like(tdepth))])
    x, y = points[..., 0], points[..., 1]
    shadow = ~occ & (np.abs(x) < 0.3) & (np.abs(y) < 0.5)          # wall the train camera cannot see
    lit = ~occ & (x < -0.7) & (x > -1.5) & (np.abs(y) < 1.0)        # wall it sees 11 degrees apart
    assert shadow.sum() > 20 and lit.sum() > 20 and occ.sum() > 10
    assert (w[shadow] > 0.99).all()
    assert (w[lit] < 0.01).all()
    assert (w[occ] < 0.01).all()  # the occluder itself is in front of the wall: observed


def test_holes_and_far_angles_are_unobserved_and_no_train_camera_means_nothing_is_observed():
    novel, train = _camera(0.0), _camera(1.0)
    depth, points, occ = _trace(novel)
    tdepth, _, _ = _trace(train)
    alpha = np.ones_like(depth)
    alpha[:, :8] = 0.0  # nothing rendered there
    views = [TrainView(train, tdepth, np.ones_like(tdepth))]
    w = unobserved_weight(novel, depth, alpha, views)
    assert (w[:, :8] == 1.0).all()
    # a train camera at a far angle (more than angle_none_deg from the novel ray) explains nothing
    strict = VisibilityConfig(angle_full_deg=1.0, angle_none_deg=5.0)
    assert (unobserved_weight(novel, depth, np.ones_like(depth), views, strict)[~occ] > 0.99).all()
    assert (unobserved_weight(novel, depth, np.ones_like(depth), []) == 1.0).all()
    # a train camera whose model render is empty there does not vouch for the surface
    empty = [TrainView(train, tdepth, np.zeros_like(tdepth))]
    assert (unobserved_weight(novel, depth, np.ones_like(depth), empty) == 1.0).all()
    with pytest.raises(InputError, match="must be the camera"):
        unobserved_weight(novel, depth[:10], alpha, views)
    with pytest.raises(InputError):
        VisibilityConfig(angle_full_deg=70.0, angle_none_deg=60.0)


def test_blend_returns_the_render_where_confidence_or_weight_is_zero():
    rng = np.random.default_rng(1)
    render = rng.random((2, 6, 5, 3)).astype(np.float32)
    restored = rng.random((2, 6, 5, 3)).astype(np.float32)
    conf = rng.random((2, 6, 5)).astype(np.float32)
    conf[0] = 0.0  # the restorer's inputs were unreliable on this frame
    weight = np.ones((2, 6, 5), np.float32)
    weight[1, :3] = 0.0  # observed pixels: the restorer may not act
    out = blend_with_render(render, RestoreResult(restored, conf, conf.mean(axis=(1, 2))), weight)
    np.testing.assert_array_equal(out.rgb[0], render[0])
    np.testing.assert_array_equal(out.rgb[1, :3], render[1, :3])
    g = conf[1, 3:, :, None]
    np.testing.assert_allclose(out.rgb[1, 3:], render[1, 3:] + g * (restored[1, 3:] - render[1, 3:]), rtol=1e-6)
    np.testing.assert_allclose(out.confidence, conf * weight, rtol=1e-6)
    full = blend_with_render(render, RestoreResult(restored, np.ones_like(conf), np.ones(2)))
    np.testing.assert_allclose(full.rgb, restored, rtol=1e-6)


def test_a_hole_takes_the_restored_frame_whatever_the_confidence():
    rng = np.random.default_rng(2)
    render = rng.random((1, 6, 5, 3)).astype(np.float32)
    restored = rng.random((1, 6, 5, 3)).astype(np.float32)
    conf = np.zeros((1, 6, 5), np.float32)  # no confidence anywhere
    weight = np.zeros((1, 6, 5), np.float32)  # every pixel observed
    alpha = np.ones((1, 6, 5), np.float32)
    alpha[0, :2] = 0.0  # nothing rendered in the first two rows
    alpha[0, 2] = 0.5  # half-way between hole_alpha_low 0.2 and hole_alpha_high 0.8
    hole = hole_weight(alpha)
    assert np.array_equal(hole[0, :2], np.ones((2, 5), np.float32)) and np.allclose(hole[0, 2], 0.5)
    assert (hole[0, 3:] == 0.0).all()
    out = blend_with_render(render, RestoreResult(restored, conf, conf.mean(axis=(1, 2))), weight, hole)
    np.testing.assert_allclose(out.rgb[0, :2], restored[0, :2], rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(out.rgb[0, 2], 0.5 * (render[0, 2] + restored[0, 2]), rtol=1e-6)
    np.testing.assert_array_equal(out.rgb[0, 3:], render[0, 3:])  # solid and observed: the render
    np.testing.assert_array_equal(out.confidence, hole)
    # where the restorer may act, the larger of the two weights wins
    conf[:] = 0.8
    weight[:] = 1.0
    out = blend_with_render(render, RestoreResult(restored, conf, conf.mean(axis=(1, 2))), weight, hole)
    np.testing.assert_allclose(out.confidence, np.maximum(hole, 0.8), rtol=1e-6)
