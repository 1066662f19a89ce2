"""Model terms decided by evidence (fixer4d.model.terms) on hand-made decomposed inits."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from fixer4d.errors import InputError
from fixer4d.init.decompose import DecomposedInit
from fixer4d.model import term_revisions as revisions
from fixer4d.model import terms as E
from fixer4d.model.spacetime import ModelConfig, SpacetimeGaussians


def _init(n_static: int = 400, n_dyn: int = 0, degree: int = 1, rotating: float = 0.0, view_std: float = 0.01,
          seed: int = 0) -> DecomposedInit:
    """A decomposed init: a static plane of points and a moving blob over 4 frames (t = 0, .25, .5, .75),
    moving along x at 1 unit per clip time; ``rotating`` of the moving points carry a fast, well
    explained angular velocity; every static point has colour std ``view_std`` across views."""
    rng = np.random.default_rng(seed)
    s = np.c_[rng.uniform(-2, 2, (n_static, 2)), np.full(n_static, -3.0)]
    frames = np.arange(4)
    times = frames / 4.0
    fr = np.repeat(frames, int(math.ceil(n_dyn / 4)))[:n_dyn]
    d = rng.normal(0, 0.1, (n_dyn, 3)) + np.c_[fr / 4.0, np.zeros(n_dyn), np.zeros(n_dyn)]
    coeffs = np.zeros((n_dyn, 3, 3))
    coeffs[:, 0, 0] = 1.0
    if degree >= 2:
        coeffs[:, 1, 1] = -2.0
    omega = np.zeros((n_dyn, 3))
    gain = np.zeros(n_dyn)
    k = int(rotating * n_dyn)
    omega[:k, 1] = 20.0
    gain[:k] = 0.9
    return DecomposedInit(
        frames=frames, times=times, static_points=s.astype(np.float32),
        static_colors=np.full((n_static, 3), 0.5, np.float32), static_view_std=np.full(n_static, view_std, np.float32),
        dyn_points=d.astype(np.float32), dyn_colors=np.full((n_dyn, 3), 0.8, np.float32), dyn_times=fr / 4.0,
        dyn_frames=fr, dyn_coeffs=coeffs.astype(np.float32), dyn_degree=np.full(n_dyn, degree, np.int8),
        dyn_fit_px=np.full(n_dyn, 0.3, np.float32), dyn_omega=omega.astype(np.float32),
        dyn_rot_gain=gain.astype(np.float32), scene_scale=5.0)


def test_static_scene_picks_no_dynamic_term():
    dec = E.decide_terms(_init(n_dyn=0))
    cfg = dec.model_config
    assert (cfg.motion_degree, cfg.rotation_velocity, cfg.temporal_opacity, cfg.sh_degree) == (0, False, False, 0)
    assert not cfg.has_time_terms
    model = E.model_from_decomposed(_init(n_dyn=0), dec, opacity=0.1, max_points=10_000)
    assert model.num_dynamic == 0 and "t_center" not in model.param_names()


def test_moving_scene_picks_motion_and_temporal_opacity():
    init = _init(n_dyn=400, degree=2, rotating=0.3)
    dec = E.decide_terms(init)
    cfg = dec.model_config
    assert cfg.motion_degree == 2 and cfg.temporal_opacity and cfg.rotation_velocity
    model = E.model_from_decomposed(init, dec, opacity=0.1, max_points=10_000)
    assert model.num_dynamic == 400 and model.num_gaussians == 800
    # motion seeded from the tracks: m1 = (1, 0, 0), m2 = (0, -2, 0) on the dynamic rows
    m = model.motion.detach()[model.dynamic].view(-1, 2, 3)
    assert torch.allclose(m[:, 0], torch.tensor([1.0, 0.0, 0.0]).expand_as(m[:, 0]))
    assert torch.allclose(m[:, 1], torch.tensor([0.0, -2.0, 0.0]).expand_as(m[:, 1]))
    # only the rotating points get omega = (0, w / 2)
    om = model.omega.detach()[model.dynamic]
    assert int((om.norm(dim=1) > 0).sum()) == 120
    assert torch.allclose(om[0], torch.tensor([0.0, 0.0, 10.0, 0.0]))


def test_linear_tracks_give_degree_one_without_rotation():
    dec = E.decide_terms(_init(n_dyn=400, degree=1))
    assert dec.model_config.motion_degree == 1
    assert not dec.model_config.rotation_velocity
    assert "rotation_velocity" in dec.reasons and "motion_degree" in dec.reasons


def test_view_dependent_static_points_switch_sh_on():
    assert E.decide_terms(_init(view_std=0.2)).model_config.sh_degree == E.SH_MAX_SUPPORTED
    assert E.decide_terms(_init(view_std=0.01)).model_config.sh_degree == 0


def test_still_points_next_to_static_ones_are_duplicates():
    init = _init(n_dyn=200, degree=0)
    init.dyn_points = init.static_points[:200].copy()  # background caught by the dilated mask
    dec = E.decide_terms(init)
    assert int(dec.dynamic_keep.sum()) == 0 and dec.evidence["duplicates_of_static"] == 200
    assert not dec.model_config.has_time_terms


def test_decisions_are_deterministic():
    a = E.decide_terms(_init(n_dyn=400, degree=2, rotating=0.3, seed=3))
    b = E.decide_terms(_init(n_dyn=400, degree=2, rotating=0.3, seed=3))
    assert a.model_config == b.model_config and a.reasons == b.reasons
    assert np.array_equal(a.dynamic_keep, b.dynamic_keep) and np.array_equal(a.rotates, b.rotates)
    ma = E.model_from_decomposed(_init(n_dyn=400, seed=3), a, opacity=0.1, max_points=500, seed=7)
    mb = E.model_from_decomposed(_init(n_dyn=400, seed=3), b, opacity=0.1, max_points=500, seed=7)
    for k, v in ma.tensors().items():
        assert torch.equal(v, mb.tensors()[k]), k


def test_forced_settings_override_the_evidence():
    init = _init(n_dyn=400, degree=2, rotating=0.3)
    forced = E.ModelTermsConfig(motion_degree=1, sh_degree=2, rotation_velocity=False, temporal_opacity=True)
    dec = E.decide_terms(init, forced)
    assert dec.model_config == ModelConfig(motion_degree=1, rotation_velocity=False, temporal_opacity=True, sh_degree=2)
    assert set(dec.forced) == {"motion_degree", "sh_degree", "rotation_velocity", "temporal_opacity"}
    assert all("forced" in dec.reasons[k] for k in dec.forced)
    # forcing motion on a static scene gives time terms but still no dynamic Gaussian to use them
    dec = E.decide_terms(_init(n_dyn=0), E.ModelTermsConfig(motion_degree=3))
    assert dec.model_config.motion_degree == 3 and int(dec.dynamic_keep.sum()) == 0


def test_modes_all_and_static():
    init = _init(n_dyn=400, degree=1)
    dec = E.decide_terms(init, E.ModelTermsConfig(mode="all"))
    assert dec.model_config == ModelConfig(3, True, True, E.SH_MAX_SUPPORTED)
    model = E.model_from_decomposed(init, dec, opacity=0.1, max_points=10_000)
    assert model.num_dynamic == model.num_gaussians == 800
    dec = E.decide_terms(init, E.ModelTermsConfig(mode="static"))
    assert not dec.model_config.has_time_terms
    model = E.model_from_decomposed(init, dec, opacity=0.1, max_points=10_000)
    assert model.num_dynamic == 0 and model.num_gaussians == 400
    with pytest.raises(InputError, match="model_terms mode"):
        E.ModelTermsConfig(mode="some")


def test_static_gaussians_skip_every_time_term():
    init = _init(n_dyn=400, degree=2, rotating=0.3)
    model = E.model_from_decomposed(init, E.decide_terms(init), opacity=0.1, max_points=10_000)
    static = ~model.dynamic
    with torch.no_grad():  # give the static rows time parameters that would move them if used
        model.motion[static] = 5.0
        model.omega[static] = 3.0
        model.t_log_scale[static] = -8.0
    for t in (0.0, 0.4, 0.9):
        snap = model.snapshot(t)
        assert torch.equal(snap.means[static], model.means.detach()[static])
        assert torch.equal(snap.quats[static], model.quats.detach()[static])
        assert torch.equal(snap.opacities[static], torch.sigmoid(model.opacity_logits.detach()[static]))


def test_point_cap_keeps_moving_points_first():
    init = _init(n_static=400, n_dyn=100, degree=1)
    model = E.model_from_decomposed(init, E.decide_terms(init), opacity=0.1, max_points=300)
    assert model.num_gaussians == 300 and model.num_dynamic == 100


def test_report_section_says_what_and_why():
    init = _init(n_dyn=400, degree=2, rotating=0.3)
    dec = E.decide_terms(init)
    model = E.model_from_decomposed(init, dec, opacity=0.1, max_points=10_000)
    rep = E.terms_report(model, dec, {"demoted": 3, "split_dynamic": 1})
    import json

    json.dumps(rep)
    assert rep["static"] == 400 and rep["dynamic"] == 400 and rep["mode"] == "auto"
    assert rep["config"]["motion_degree"] == 2 and rep["revisions"]["demoted"] == 3
    assert set(rep["reasons"]) >= {"motion_degree", "rotation_velocity", "temporal_opacity", "sh_degree"}
    assert rep["init"]["point_degree_histogram"] == [0, 0, 400, 0]


def _dyn_model(n: int = 3) -> SpacetimeGaussians:
    pts = np.zeros((n, 3))
    return SpacetimeGaussians.from_points(pts + np.arange(n)[:, None], np.full((n, 3), 0.5), np.full(n, 0.5),
                                          ModelConfig(1, False, True, 0), scales=np.full(n, 0.1))


def test_demotion_of_gaussians_that_neither_move_nor_fade():
    model = _dyn_model()
    with torch.no_grad():
        model.t_log_scale[:] = math.log(10.0)  # fades by < 1% across the clip
        model.motion[1] = torch.tensor([1.0, 0.0, 0.0])  # moves 0.5 >> 0.05 (half its size)
        model.t_log_scale[2] = math.log(0.1)  # time-local
    assert revisions.demote_candidates(model).tolist() == [True, False, False]
    counts = revisions.revise_terms(model, None, revisions.TemporalStats.zeros(3), grad_threshold=2e-4, max_gaussians=100)
    assert counts == {"demoted": 1, "split_dynamic": 0}
    assert model.dynamic.tolist() == [False, True, True]


def test_static_gaussian_with_a_time_local_residual_is_split():
    model = _dyn_model(4)
    model.set_dynamic(torch.tensor([False, False, True, True]))
    with torch.no_grad():
        model.t_log_scale[:] = math.log(0.1)
    stats = revisions.TemporalStats.zeros(4)
    grad = torch.zeros(4, 2)
    grad[0] = torch.tensor([1e-2, 0.0])  # hot, only at t in bin 2
    grad[1] = torch.tensor([1e-2, 0.0])  # hot at every time: not a temporal residual
    for t in (0.1, 0.3, 0.6, 0.9):
        for _ in range(4):
            stats.update(grad * (1.0 if t == 0.6 else 0.0) + torch.tensor([[0.0, 0.0], [1e-2, 0.0], [0, 0], [0, 0]]),
                         torch.ones(4), 100, 100, t)
    counts = revisions.revise_terms(model, None, stats, grad_threshold=2e-4, max_gaussians=100)
    assert counts["split_dynamic"] == 1
    assert model.num_gaussians == 5 and model.dynamic.tolist() == [False, False, True, True, True]
    assert float(model.t_center.detach()[4]) == pytest.approx(2.5 / revisions.TEMPORAL_BINS)
    assert torch.equal(model.means[4], model.means[0])
    # no budget left: nothing is split
    full = _dyn_model(4)
    full.set_dynamic(torch.tensor([False, False, True, True]))
    counts = revisions.revise_terms(full, None, stats, grad_threshold=2e-4, max_gaussians=4)
    assert counts["split_dynamic"] == 0 and full.num_gaussians == 4
