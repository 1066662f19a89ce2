"""The depth prior (``training.depth_prior``): its targets are the init's nearest visible points,
its loss is a clipped relative error whose gradient reaches the Gaussians' positions, stage 1
pulls the rendered depth towards the targets, the moving pixels of a non-init frame have no
static target, and off (or the sparse baseline) keys and trains as before."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from fixer4d.errors import InputError
from fixer4d.geometry.camera import Camera
from fixer4d.init.cloud import FrameCloud
from fixer4d.init.decompose import DecomposedInit
from fixer4d.pipeline.config import resolve
from fixer4d.pipeline.keys import stage1_key
from fixer4d.render.api import render
from fixer4d.train.checkpoints import result_settings
from fixer4d.train.config import TrainingConfig
from fixer4d.train.depth_prior import RELATIVE_CLIP, DepthPriorConfig, DepthTargets, depth_loss, point_depth
from fixer4d.train.model_init import model_from_clouds
from fixer4d.train.trainer import Trainer


def _camera() -> Camera:
    return Camera.look_at(eye=(0.0, 0.0, -4.0), target=(0.0, 0.0, 0.0), width=40, height=30)


def _plane(z: float, step: float, half: float = 1.0) -> np.ndarray:
    g = np.arange(-half, half + 1e-9, step)
    x, y = np.meshgrid(g, g)
    return np.stack([x.ravel(), y.ravel(), np.full(x.size, z)], axis=1)


def test_point_depth_keeps_the_nearest_surface_and_drops_what_shows_through_its_holes():
    cam = _camera()
    near = _plane(0.0, 0.25)  # 4 units from the camera, a sparse grid: holes between its points
    far = _plane(4.0, 0.05, half=3.0)  # 8 units away, dense, wider: in the near grid's holes and around it
    z = point_depth(np.concatenate([near, far]), cam, tolerance=0.05, window=5)
    assert z.shape == (30, 40) and z.dtype == np.float32
    uv, depth = cam.project(near)
    cols, rows = np.floor(uv[:, 0]).astype(int), np.floor(uv[:, 1]).astype(int)
    inside = (cols >= 0) & (cols < 40) & (rows >= 0) & (rows < 30)
    assert np.allclose(z[rows[inside], cols[inside]], depth[inside], rtol=1e-5)
    # where the far plane shows between near points, it is dropped; where only it is, it is kept
    region = np.zeros_like(z, bool)
    region[rows[inside].min():rows[inside].max() + 1, cols[inside].min():cols[inside].max() + 1] = True
    assert not np.any(z[region] > 6.0)
    assert np.any(z[~region] > 7.5)
    # nothing, a point behind the camera: no target
    assert not point_depth(np.zeros((0, 3)), cam, 0.05, 5).any()
    assert not point_depth(np.array([[0.0, 0.0, -6.0]]), cam, 0.05, 5).any()


def test_depth_loss_is_a_clipped_relative_error_with_a_gradient_below_the_clip():
    target = torch.tensor([[2.0, 4.0, 0.0], [1.0, 0.0, 0.0]])
    depth = torch.tensor([[2.2, 4.0, 9.0], [3.0, 0.0, 0.0]], requires_grad=True)
    loss = depth_loss(depth, target)
    # (0.1 + 0 + clip) over the 3 pixels with a target; pixels without one count nothing
    assert float(loss.detach()) == pytest.approx((0.1 + 0.0 + RELATIVE_CLIP) / 3)
    loss.backward()
    g = depth.grad
    assert float(g[0, 0]) == pytest.approx(1 / 2 / 3) and float(g[1, 0]) == 0.0  # clipped: no pull
    assert float(g[0, 2]) == 0.0 and float(g[1, 1]) == 0.0
    assert float(depth_loss(torch.ones(2, 2), torch.zeros(2, 2))) == 0.0
    assert float(depth_loss(target, target)) == 0.0


def test_settings_are_checked_and_key_the_stage_only_when_on_and_only_for_the_dense_init():
    with pytest.raises(InputError):
        DepthPriorConfig(weight=-1.0)
    with pytest.raises(InputError):
        DepthPriorConfig(window=4)
    with pytest.raises(InputError, match="unknown keys"):
        TrainingConfig(depth_prior={"weight": 0.1, "scale": 2})
    assert not TrainingConfig().depth_prior.enabled
    assert "depth_prior" not in result_settings(TrainingConfig().to_dict())
    on = resolve(overrides={"training.depth_prior.weight": 0.5}, defaults={})
    off = resolve(overrides={}, defaults={})
    assert on.training.depth_prior.weight == 0.5
    assert stage1_key(on, "mvs") != stage1_key(off, "mvs")
    assert stage1_key(on, "sparse") == stage1_key(off, "sparse")  # the paper's STGS baseline trains without it


def _decomposed(static: np.ndarray, moving: np.ndarray, frame: int) -> DecomposedInit:
    n, m = len(static), len(moving)
    f32 = np.float32
    return DecomposedInit(frames=np.array([frame]), times=np.array([0.0]), static_points=static.astype(f32),
                          static_colors=np.full((n, 3), 0.5, f32), static_view_std=np.zeros(n, f32),
                          dyn_points=moving.astype(f32), dyn_colors=np.full((m, 3), 0.5, f32),
                          dyn_times=np.zeros(m), dyn_frames=np.full(m, frame), dyn_coeffs=np.zeros((m, 3, 3), f32),
                          dyn_degree=np.zeros(m, np.int8), dyn_fit_px=np.zeros(m, f32),
                          dyn_omega=np.zeros((m, 3), f32), dyn_rot_gain=np.zeros(m, f32), scene_scale=1.0)


def test_static_targets_leave_out_a_frames_moving_pixels_and_init_frames_add_their_moving_points():
    cam = _camera()
    wall = _plane(4.0, 0.04, half=6.0)
    person = _plane(1.0, 0.02, half=0.2)  # in front of the wall at the init frame 0
    moving = np.zeros((30, 40), bool)
    moving[10:20, 15:25] = True
    targets = DepthTargets(_decomposed(wall, person, 0), [cam], DepthPriorConfig(weight=1.0, window=3),
                           lambda view, frame: moving)
    at_init = targets.target(0, 0).numpy()
    other = targets.target(0, 3).numpy()
    assert 4.5 < at_init[15, 20] < 5.5  # the person, 5 units away
    assert other[15, 20] == 0.0 and other[9, 20] == 0.0  # the mask, grown by one pixel
    assert other[5, 5] == pytest.approx(8.0, rel=1e-4) and at_init[5, 5] == pytest.approx(8.0, rel=1e-4)
    per_frame = DepthTargets([FrameCloud(2, 0.5, wall, np.zeros_like(wall))], [cam], DepthPriorConfig(weight=1.0),
                             lambda view, frame: moving)
    assert per_frame.target(0, 0) is None and per_frame.target(0, 2) is not None


def _mean_depth_error(trainer: Trainer, scene, targets: DepthTargets) -> float:
    errs = []
    with torch.no_grad():
        for v, cid in enumerate(scene.train_ids):
            for f in range(scene.num_frames):
                target = targets.target(v, f)
                out = render(trainer.model.at(scene.time(f)), scene.cameras[cid])
                errs.append(float(depth_loss(out.depth, target)))
    return float(np.mean(errs))


def test_stage1_pulls_the_rendered_depth_towards_the_targets(small_scene, small_clouds, make_config):
    # targets 15 % behind the true surfaces: with the prior the rendered depth moves towards them
    cameras = small_scene.train_cameras
    centre = np.mean([c.center for c in cameras], axis=0)
    pushed = [FrameCloud(c.frame, c.time, centre + (c.points - centre) * 1.15, c.colors) for c in small_clouds]
    errors = {}
    for weight in (0.0, 1.0):
        cfg = make_config(40, densify_from=1000, densify_until=1000, init_max_points=600,
                          depth_prior={"weight": weight})
        trainer = Trainer(model_from_clouds(small_clouds, small_scene, cfg), small_scene, cfg, depth_init=pushed)
        assert (trainer.depth_targets is None) == (weight == 0.0)
        trainer.train()
        assert all(bool(torch.isfinite(p).all()) for p in trainer.model.parameters())
        probe = DepthTargets(pushed, cameras, DepthPriorConfig(weight=1.0), lambda v, f: np.zeros((1, 1), bool))
        errors[weight] = _mean_depth_error(trainer, small_scene, probe)
    assert errors[1.0] < 0.9 * errors[0.0], errors  # measured: 0.134 against 0.162
