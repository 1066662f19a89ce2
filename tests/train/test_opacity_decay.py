"""The learned opacity decay (``training.opacity_decay``): its gradient reaches the opacities and
the network, it decays only what the step's views see at the step's time, it replaces the resets
in stage 1 only, a resumed run reproduces the uninterrupted one, and off changes nothing."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from fixer4d.errors import InputError
from fixer4d.geometry.camera import Camera
from fixer4d.model.spacetime import ModelConfig, SpacetimeGaussians
from fixer4d.pipeline.config import resolve
from fixer4d.pipeline.keys import stage1_key
from fixer4d.train.checkpoints import result_settings
from fixer4d.train.config import Stage2Config, TrainingConfig, matched_config
from fixer4d.train.model_init import model_from_clouds
from fixer4d.train.opacity_decay import OpacityDecay, OpacityDecayConfig, present_at, seen_by
from fixer4d.train.schedule import StageSchedule
from fixer4d.train.trainer import Trainer


def _camera() -> Camera:
    return Camera.look_at(eye=(0.0, 0.0, -4.0), target=(0.0, 0.0, 0.0), width=64, height=48)


def _model(points: np.ndarray, times: np.ndarray) -> SpacetimeGaussians:
    return SpacetimeGaussians.from_points(points, np.full_like(points, 0.5), times, ModelConfig(), opacity=0.5)


def test_the_decay_gradient_reaches_the_opacities_and_the_network():
    model = _model(np.array([[0.0, 0.0, 0.0], [0.2, 0.1, 0.0], [-0.3, 0.0, 0.5]]), np.array([0.5, 0.5, 0.5]))
    decay = OpacityDecay(OpacityDecayConfig(enabled=True), torch.device("cpu"))
    before = torch.sigmoid(model.opacity_logits.detach()).clone()
    used = decay.opacities(model, 0.5, [_camera()], extent=4.0)
    (used * torch.arange(1.0, 4.0)).sum().backward()
    assert model.opacity_logits.grad is not None and bool((model.opacity_logits.grad != 0).all())
    grads = [p.grad for p in decay.network.parameters()]
    assert all(g is not None for g in grads) and any(bool((g != 0).any()) for g in grads)
    # the decayed opacities were written back, inside [f_min, f_max] x the old ones
    after = torch.sigmoid(model.opacity_logits.detach())
    ratio = after / before
    assert bool((ratio >= 0.996 - 1e-6).all() and (ratio <= 0.998 + 1e-6).all()), ratio
    assert torch.allclose(after, used.detach(), atol=1e-6)


def test_only_what_the_views_see_at_the_step_time_decays():
    # in view / behind the camera / outside the image; the first two at the step's time
    points = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, -6.0], [40.0, 0.0, 0.0], [0.1, 0.0, 0.0]])
    model = _model(points, np.array([0.5, 0.5, 0.5, 0.0]))
    with torch.no_grad():
        model.t_log_scale.fill_(np.log(0.1))  # lifetime ~0.1: the 4th Gaussian (t = 0) is gone at 0.5
    cam = _camera()
    assert seen_by(model.means.detach(), [cam], extent=4.0).tolist() == [True, False, False, True]
    assert present_at(model, 0.5).tolist() == [True, True, True, False]
    model.set_frozen(torch.tensor([False, False, False, False]))
    decay = OpacityDecay(OpacityDecayConfig(enabled=True, f_min=0.5, f_max=0.5), torch.device("cpu"))
    decay.opacities(model, 0.5, [cam], extent=4.0)
    assert torch.allclose(torch.sigmoid(model.opacity_logits.detach()), torch.tensor([0.25, 0.5, 0.5, 0.5]))
    # frozen rows (a later segment's shared static Gaussians) never decay
    model.set_frozen(torch.tensor([True, False, False, False]))
    decay.opacities(model, 0.5, [cam], extent=4.0)
    assert torch.allclose(torch.sigmoid(model.opacity_logits.detach()), torch.tensor([0.25, 0.5, 0.5, 0.5]))


def test_the_decay_replaces_the_resets_in_stage1_only():
    on = TrainingConfig.for_iterations(1500, opacity_decay={"enabled": True})
    assert isinstance(on.opacity_decay, OpacityDecayConfig)
    s1 = StageSchedule.stage1(on)
    assert s1.opacity_reset_every is None and s1.decay_from == on.densify_from
    assert not s1.decays(on.densify_from - 1) and s1.decays(on.densify_from) and s1.decays(1499)
    assert StageSchedule.stage1(TrainingConfig.for_iterations(1500, opacity_decay={"enabled": True, "start": 7})).decay_from == 7
    half = StageSchedule.stage1(TrainingConfig.for_iterations(1500, opacity_decay={"enabled": True, "until_fraction": 0.5}))
    assert half.decays(749) and not half.decays(750)
    assert StageSchedule.stage2(on, Stage2Config()).decay_from is None
    assert StageSchedule.stage1(matched_config(on, Stage2Config())).decay_from is None
    off = StageSchedule.stage1(TrainingConfig.for_iterations(1500, opacity_decay={"enabled": False}))
    assert off.decay_from is None and off.opacity_reset_every == 500
    assert TrainingConfig().opacity_decay.enabled  # the default since five seeds chose it


def test_decay_settings_are_checked_and_key_the_stage_only_when_on():
    with pytest.raises(InputError):
        OpacityDecayConfig(f_min=0.999, f_max=0.99)
    with pytest.raises(InputError, match="unknown keys"):
        TrainingConfig(opacity_decay={"enabled": True, "rate": 2})
    # the reset keys its stages as every training did before the decay existed
    assert "opacity_decay" not in result_settings(TrainingConfig(opacity_decay={"enabled": False}).to_dict())
    assert result_settings(TrainingConfig().to_dict())["opacity_decay"]["enabled"]
    reset = resolve(overrides={"training.opacity_decay.enabled": False}, defaults={})
    on = resolve(overrides={}, defaults={})
    assert on.training.opacity_decay.enabled and not reset.training.opacity_decay.enabled
    assert stage1_key(reset, "mvs") != stage1_key(on, "mvs")


def _decay_config(make_config) -> TrainingConfig:
    return make_config(12, densify_from=2, densify_every=3, densify_until=11, checkpoint_every=6,
                       init_max_points=600, opacity_decay={"enabled": True})


def test_resume_with_decay_equals_uninterrupted(small_scene, small_clouds, make_config, tmp_path):
    cfg = _decay_config(make_config)
    straight = Trainer(model_from_clouds(small_clouds, small_scene, cfg), small_scene, cfg, run_dir=tmp_path / "a")
    straight.train()
    first = Trainer(model_from_clouds(small_clouds, small_scene, cfg), small_scene, cfg, run_dir=tmp_path / "b")
    first.train(6)
    del first
    resumed = Trainer(model_from_clouds(small_clouds, small_scene, cfg), small_scene, cfg, run_dir=tmp_path / "b")
    assert resumed.resume() and resumed.step_count == 6
    resumed.train()
    for (name, a), (_, b) in zip(straight.model.named_parameters(), resumed.model.named_parameters()):
        assert torch.equal(a, b), name
    for a, b in zip(straight.decay.network.parameters(), resumed.decay.network.parameters()):
        assert torch.equal(a, b)
    # the network really trained
    fresh = OpacityDecay(cfg.opacity_decay, torch.device("cpu")).network
    assert any(not torch.equal(a, b) for a, b in zip(fresh.parameters(), straight.decay.network.parameters()))


def test_decay_lowers_opacities_that_no_view_supports(small_scene, small_clouds, make_config):
    # a stage-1 run with and without the decay from the same init: with it the mean opacity of
    # the model falls (what the views do not hold up fades) and training stays finite
    runs = {}
    for enabled in (False, True):
        cfg = make_config(60, densify_from=1000, densify_until=1000, init_max_points=600,
                          opacity_decay={"enabled": enabled, "start": 0})
        trainer = Trainer(model_from_clouds(small_clouds, small_scene, cfg), small_scene, cfg)
        trainer.train()
        assert all(bool(torch.isfinite(p).all()) for p in trainer.model.parameters())
        runs[enabled] = float(torch.sigmoid(trainer.model.opacity_logits.detach()).mean())
    assert runs[True] < 0.96 * runs[False], runs  # measured: 0.165 against 0.179
