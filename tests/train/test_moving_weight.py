"""Stage 1 on moving content: the observed loss weighted by the train cameras' own moving masks,
and densification statistics that count only the views where a Gaussian is really drawn."""
from __future__ import annotations

import numpy as np
import torch

from fixer4d.errors import InputError
from fixer4d.init.masks import moving_masks_for_scene
from fixer4d.model.spacetime import SpacetimeGaussians
from fixer4d.train import losses
from fixer4d.train.model_init import model_from_clouds
from fixer4d.train.trainer import Trainer


def _pair(h=24, w=32, seed=0):
    g = torch.Generator().manual_seed(seed)
    a = torch.rand(h, w, 3, generator=g)
    b = (a + 0.3 * torch.rand(h, w, 3, generator=g)).clamp(0, 1)
    return a, b


def test_weighted_stg_loss_ones_is_plain_and_zero_weight_ignores_pixels():
    a, b = _pair()
    ones = torch.ones(24, 32)
    assert torch.allclose(losses.stg_loss(a, b, ones), losses.stg_loss(a, b), atol=1e-6)
    # the weighted loss only sees the weighted region: changing pixels far from it (more than
    # the SSIM window's half-width away) changes nothing
    w = torch.zeros(24, 32)
    w[:, :8] = 1.0
    b2 = b.clone()
    b2[:, 20:] = 1.0 - b2[:, 20:]
    assert torch.allclose(losses.stg_loss(a, b, w), losses.stg_loss(a, b2, w), atol=1e-6)
    assert not torch.allclose(losses.stg_loss(a, b), losses.stg_loss(a, b2), atol=1e-3)
    # a larger weight on the region raises the loss in proportion to its share
    assert float(losses.stg_loss(a, b, 1.0 + 4.0 * (w > 0))) > float(losses.stg_loss(a, b)) * 1.5


def test_weighted_ssim_rejects_a_wrong_weight_shape():
    a, b = _pair()
    try:
        losses.ssim(a, b, torch.ones(10, 10))
    except InputError as exc:
        assert "weight shape" in str(exc)
    else:
        raise AssertionError("a weight of the wrong shape was accepted")


def test_pixel_weight_follows_each_train_camera_own_moving_mask(small_scene, small_clouds, make_config):
    cfg0 = make_config(5, init_max_points=300, moving_loss_weight=0.0)
    model = model_from_clouds(small_clouds, small_scene, cfg0)
    assert Trainer(model, small_scene, cfg0)._pixel_weight(0, 1) is None  # weight 0: plain loss
    cfg = make_config(5, init_max_points=300, moving_loss_weight=3.0)
    tr = Trainer(model_from_clouds(small_clouds, small_scene, cfg), small_scene, cfg)
    frames = list(range(small_scene.num_frames))
    masks = moving_masks_for_scene(small_scene, small_scene.train_ids, frames)
    assert masks.any(), "the tiny scene has moving content"
    for v in range(len(small_scene.train_ids)):
        for f in frames:
            w = tr._pixel_weight(v, f).numpy()
            assert w.shape == masks[v, f].shape
            np.testing.assert_array_equal(w, np.where(masks[v, f], 4.0, 1.0))
    tr.train()  # trains with the weighted loss
    assert np.isfinite(tr.history[-1]["loss"])


def test_densify_stats_skip_views_where_a_time_local_gaussian_is_invisible(small_scene, small_clouds, make_config):
    """A dynamic Gaussian living at t ~ 0 with a tiny temporal std is on screen at every frame but
    drawn only at frame 0: its statistics count only those views."""
    cfg = make_config(40, init_max_points=300, densify_from=1, densify_until=10_000, densify_every=10_000)
    base = model_from_clouds(small_clouds, small_scene, cfg)
    t = base.tensors()
    n = base.num_gaussians
    t["t_center"] = torch.zeros(n)
    t["t_log_scale"] = torch.full((n,), float(np.log(1e-3)))  # ~invisible one frame away
    model = SpacetimeGaussians.from_tensors(base.config, t)
    tr = Trainer(model, small_scene, cfg)
    assert small_scene.time(0) == 0.0
    drawn_steps = 0
    for _ in range(40):
        peek = np.random.Generator(np.random.PCG64())  # the frame the next step draws
        peek.bit_generator.state = tr.rng.bit_generator.state
        frame = int(peek.integers(0, small_scene.num_frames))
        denom_before = tr.stats.denom.clone()
        tr.step()
        grew = bool((tr.stats.denom > denom_before).any())
        if frame == 0:
            drawn_steps += 1
            assert grew, "frame 0: the Gaussians are drawn there and must be counted"
        else:
            assert not grew, f"frame {frame}: Gaussians invisible at that time were counted as drawn"
    assert 0 < drawn_steps < 40
