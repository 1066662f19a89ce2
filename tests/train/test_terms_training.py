"""Stage 1 with model terms decided by evidence: the model from a decomposed init trains, the
revisions (demote / split) run on the density schedule and survive a resume exactly."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from fixer4d.init.decompose import DecomposedInit
from fixer4d.model.terms import ModelTermsConfig
from fixer4d.train.model_init import model_from_init
from fixer4d.train.trainer import Trainer


@pytest.fixture(scope="module")
def small_decomposed(small_clouds):
    """A decomposed init from the ground-truth depth clouds: frame 0 as the static cloud and
    every 8th point of each frame as a time-local moving point with a linear track."""
    static = small_clouds[0]
    pts, cols, frames = [], [], []
    for c in small_clouds:
        pts.append(c.points[::8])
        cols.append(c.colors[::8])
        frames.append(np.full(len(c.points[::8]), c.frame))
    frames = np.concatenate(frames)
    m = len(frames)
    coeffs = np.zeros((m, 3, 3), np.float32)
    coeffs[:, 0, 0] = 0.5
    times = np.array([c.time for c in small_clouds])
    return DecomposedInit(
        frames=np.array([c.frame for c in small_clouds]), times=times,
        static_points=static.points, static_colors=static.colors, static_view_std=np.zeros(len(static), np.float32),
        dyn_points=np.concatenate(pts), dyn_colors=np.concatenate(cols), dyn_times=times[frames], dyn_frames=frames,
        dyn_coeffs=coeffs, dyn_degree=np.ones(m, np.int8), dyn_fit_px=np.full(m, 0.2, np.float32),
        dyn_omega=np.zeros((m, 3), np.float32), dyn_rot_gain=np.zeros(m, np.float32), scene_scale=4.0)


def _config(make_config):
    # densify (and revise) at 3, 6, 9; the checkpoint at 6 cuts through the statistics
    return make_config(12, densify_from=2, densify_every=3, densify_until=11, opacity_reset_every=5,
                       checkpoint_every=6, init_max_points=900)


def test_auto_model_trains_and_records_revisions(small_scene, small_decomposed, make_config):
    cfg = _config(make_config)
    model, decision = model_from_init(small_decomposed, small_scene, cfg, ModelTermsConfig())
    assert decision is not None and decision.model_config.temporal_opacity
    n_dyn = model.num_dynamic
    assert 0 < n_dyn < model.num_gaussians
    trainer = Trainer(model, small_scene, cfg, terms=ModelTermsConfig())
    assert trainer.revise
    while trainer.step_count < trainer.total_iterations:
        rec = trainer.step()
        # a static Gaussian turns dynamic only by a split_dynamic revision; densification copies
        # Gaussians as they are (at most one new dynamic row per clone or split)
        copies = sum(rec.get(f"densify_{k}", 0.0) for k in ("split_dynamic", "cloned", "split"))
        assert trainer.model.num_dynamic <= n_dyn + copies
        n_dyn = trainer.model.num_dynamic
    assert set(trainer.revisions) == {"demoted", "split_dynamic"}
    assert len(trainer.temporal_stats) == trainer.model.num_gaussians


def test_revisions_are_off_outside_auto(small_scene, small_decomposed, make_config):
    cfg = _config(make_config)
    for terms in (ModelTermsConfig(mode="all"), ModelTermsConfig(revise=False), None):
        model, _ = model_from_init(small_decomposed, small_scene, cfg, terms)
        assert not Trainer(model, small_scene, cfg, terms=terms).revise


def test_resume_with_revisions_equals_uninterrupted(small_scene, small_decomposed, make_config, tmp_path):
    cfg = _config(make_config)
    terms = ModelTermsConfig()

    def fresh(run_dir):
        return Trainer(model_from_init(small_decomposed, small_scene, cfg, terms)[0], small_scene, cfg,
                       run_dir=run_dir, terms=terms)

    straight = fresh(tmp_path / "a")
    straight.train()
    first = fresh(tmp_path / "b")
    first.train(6)
    del first
    resumed = fresh(tmp_path / "b")
    assert resumed.resume() and resumed.step_count == 6
    resumed.train()
    a, b = dict(straight.model.named_parameters()), dict(resumed.model.named_parameters())
    for name in a:
        assert torch.equal(a[name], b[name]), name
    assert torch.equal(straight.model.dynamic, resumed.model.dynamic)
    assert straight.revisions == resumed.revisions
