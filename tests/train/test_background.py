"""``training.background``: "mean" is the train views' mean colour, read from the train cameras
only (a held-out camera's frames never), the same whatever the order of the additions; a training
and its renders use it where nothing covers a pixel; bad values fail with what to give."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from fixer4d.calib.sfm import spread_frames
from fixer4d.errors import InputError
from fixer4d.geometry.camera import Camera
from fixer4d.pipeline.config import resolve
from fixer4d.render.api import render
from fixer4d.scene.train_view import TrainOnlyView
from fixer4d.train.background import MEAN, MEAN_FRAMES, check_background, resolve_background, train_views_mean
from fixer4d.train.config import TrainingConfig
from fixer4d.train.model_init import model_from_clouds
from fixer4d.train.trainer import Trainer


def test_values_are_checked_and_round_trip_through_the_config():
    assert check_background("mean") == MEAN
    assert check_background([0.5, 0.25, 1]) == (0.5, 0.25, 1.0)
    for bad in ("grey", [0.5, 0.5], [0.5, 0.5, 1.5], [0.5, float("nan"), 0.5], None):
        with pytest.raises(InputError, match="3 numbers in"):
            check_background(bad)
    assert TrainingConfig().background == MEAN  # the default: +3 dB on Panoptic's validation cameras
    assert TrainingConfig.from_dict(TrainingConfig().to_dict()).background == MEAN
    assert TrainingConfig.from_dict({"background": [0, 0, 0]}).background == (0.0, 0.0, 0.0)
    assert resolve(overrides={"training.background": [0.1, 0.2, 0.3]}, defaults={}).training.background == (0.1, 0.2, 0.3)


class _Spy:
    """A scene whose ``frame`` records the cameras read."""

    def __init__(self, scene):
        self.scene, self.read = scene, set()

    def __getattr__(self, name):
        return getattr(self.scene, name)

    def frame(self, f, cam):
        self.read.add(int(cam))
        return self.scene.frame(f, cam)


def test_the_mean_is_the_train_views_own_and_reads_no_held_out_camera(small_scene):
    spy = _Spy(small_scene)
    rgb = train_views_mean(spy)
    assert spy.read == set(small_scene.train_ids)
    frames = spread_frames(small_scene.num_frames, MEAN_FRAMES)
    want = np.mean([small_scene.frame(f, c).reshape(-1, 3).astype(np.float64)
                    for c in small_scene.train_ids for f in frames], axis=(0, 1))
    assert np.allclose(rgb, want, atol=1e-6)
    # a fold's view: its own cameras only, whatever the scene's other train cameras hold
    fold = TrainOnlyView(small_scene, small_scene.train_ids[:2], readable=small_scene.train_ids[:2])
    assert resolve_background(MEAN, fold) != rgb
    assert resolve_background((0.1, 0.2, 0.3), fold) == (0.1, 0.2, 0.3)


def test_the_sum_is_exact_for_8_bit_frames_whatever_the_order():
    rng = np.random.default_rng(0)
    image = (rng.integers(0, 256, size=(180, 320, 3)) / 255.0).astype(np.float32)
    flat = image.reshape(-1, 3).astype(np.float64)
    forward, backward = flat.sum(axis=0), flat[::-1].sum(axis=0)
    shuffled = flat[rng.permutation(len(flat))]
    assert np.array_equal(forward, backward) and np.array_equal(forward, np.add.reduce(shuffled, axis=0))


def test_a_training_and_its_renders_show_the_mean_where_nothing_covers_a_pixel(small_scene, small_clouds, make_config):
    cfg = make_config(2, init_max_points=50)
    trainer = Trainer(model_from_clouds(small_clouds, small_scene, cfg), small_scene, cfg)
    mean = resolve_background(MEAN, small_scene)
    assert torch.allclose(trainer.background, torch.tensor(mean))
    cam = small_scene.cameras[small_scene.train_ids[0]]
    away = Camera.look_at(cam.center, 2 * cam.center - trainer.model.means.detach().mean(0).numpy(),
                          K=cam.K, width=cam.width, height=cam.height)  # a view where no Gaussian lies
    out = render(trainer.model.at(0.0), away, background=trainer.background)
    assert bool((out.alpha < 1e-6).all())
    assert torch.allclose(out.rgb, trainer.background.expand_as(out.rgb))
