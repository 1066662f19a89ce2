"""The "Restoration" rows' render function (restored renders at the held-out cameras)."""
from __future__ import annotations

import dataclasses

import numpy as np

from fixer4d.bench.iteration import depth_clouds
from fixer4d.pipeline.restoration import restoration_render_fn
from fixer4d.restore.reference_warp import ReferenceWarpRestorer
from fixer4d.scene import load_scene
from fixer4d.train.config import TrainingConfig
from fixer4d.train.model_init import model_from_clouds


def test_a_held_out_camera_on_a_train_cameras_pose_is_restored():
    """A held-out camera that duplicates a train camera's pose (an adversarial split) has no
    path to that camera; its clip uses the pose itself instead of failing the whole run."""
    scene = load_scene("tiny")
    model = model_from_clouds(depth_clouds(scene, stride=4), scene, TrainingConfig(init_max_points=800, progress=False))
    fn = restoration_render_fn(model, scene, ReferenceWarpRestorer())
    train = scene.cameras[scene.train_ids[0]]
    duplicate = dataclasses.replace(train, name="held_out_on_train_pose")
    held_out = scene.cameras[scene.test_ids[0]]
    for cam in (duplicate, held_out):
        img = fn(cam, scene.time(1))
        assert img.shape == (cam.height, cam.width, 3) and np.isfinite(img).all()
