"""The sparse baseline's init survives frames with 1-3 triangulated points: a frame's
only point takes its scale from the points of every frame instead of a NaN."""
from __future__ import annotations

import numpy as np
import torch

from fixer4d.init.cloud import FrameCloud
from fixer4d.train.config import TrainingConfig
from fixer4d.train.model_init import MIN_INIT_POINTS, model_from_clouds


def test_frames_with_one_two_and_three_points_get_finite_scales(small_scene):
    rng = np.random.default_rng(0)
    sizes = [1, 2, 3]
    assert sum(sizes) >= MIN_INIT_POINTS  # no random top-up: every scale comes from the frames' points
    clouds = [FrameCloud(f, small_scene.time(f), rng.random((n, 3)), rng.random((n, 3))) for f, n in enumerate(sizes)]
    model = model_from_clouds(clouds, small_scene, TrainingConfig(init_opacity=0.1))
    assert model.num_gaussians == sum(sizes)
    for name, p in model.named_parameters():
        assert torch.isfinite(p).all(), name
