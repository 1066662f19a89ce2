"""SpacetimeGaussians: the equations, the switchable effects and the static fast path."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from fixer4d.errors import InputError
from fixer4d.model.initial_scales import knn_scales
from fixer4d.model.sh import SH_C0, SH_C1
from fixer4d.model.spacetime import ModelConfig, SpacetimeGaussians

FIELDS = ("means", "quats", "scales", "opacities", "colors")


def random_model(n: int = 64, config: ModelConfig | None = None, seed: int = 0,
                 dtype: torch.dtype = torch.float32) -> SpacetimeGaussians:
    """A model with every Parameter random (so no time term vanishes by accident)."""
    config = ModelConfig() if config is None else config
    g = torch.Generator().manual_seed(seed)
    m = SpacetimeGaussians(config, n, dtype=dtype)
    with torch.no_grad():
        for name in m.param_names():
            p = getattr(m, name)
            p.copy_(torch.randn(p.shape, generator=g, dtype=dtype) * 0.5)
        if "t_center" in m.param_names():
            m.t_center.uniform_(0.0, 1.0, generator=g)
    return m


def numpy_at(m: SpacetimeGaussians, t: float) -> dict[str, np.ndarray]:
    """docs/design.md §9 written out independently in float64 numpy, every Gaussian dynamic."""
    p = {k: v.detach().double().numpy() for k, v in m.tensors().items()}
    cfg = m.config
    dt = t - p["t_center"] if cfg.has_time_terms else np.zeros(len(p["means"]))
    means = p["means"].copy()
    for k in range(cfg.motion_degree):
        means += p["motion"][:, 3 * k:3 * k + 3] * dt[:, None] ** (k + 1)
    quats = p["quats"] + (p["omega"] * dt[:, None] if cfg.rotation_velocity else 0.0)
    opac = 1.0 / (1.0 + np.exp(-p["opacity_logits"]))
    if cfg.temporal_opacity:
        opac = opac * np.exp(-(dt / np.exp(p["t_log_scale"])) ** 2)
    colors = np.maximum(0.5 + SH_C0 * p["colors"], 0.0)
    return {"means": means, "quats": quats, "scales": np.exp(p["log_scales"]), "opacities": opac, "colors": colors}


@pytest.mark.parametrize("config", [
    ModelConfig(),
    ModelConfig(motion_degree=1, rotation_velocity=False, temporal_opacity=True),
    ModelConfig(motion_degree=2, rotation_velocity=True, temporal_opacity=False),
    ModelConfig(motion_degree=0, rotation_velocity=True, temporal_opacity=False),
])
@pytest.mark.parametrize("t", [0.0, 0.37, 1.0])
def test_at_matches_the_equations(config, t):
    m = random_model(50, config, dtype=torch.float64)
    snap = m.at(t)
    ref = numpy_at(m, t)
    for f in FIELDS:
        np.testing.assert_allclose(getattr(snap, f).detach().numpy(), ref[f], rtol=1e-12, atol=1e-12, err_msg=f)


def test_disabled_effects_have_no_parameters():
    static = SpacetimeGaussians(ModelConfig(0, False, False, 0), 10)
    assert static.param_names() == ["means", "log_scales", "quats", "opacity_logits", "colors"]
    assert {n for n, _ in static.named_parameters()} == set(static.param_names())
    m1 = SpacetimeGaussians(ModelConfig(motion_degree=1, rotation_velocity=False, temporal_opacity=False), 10)
    assert m1.motion.shape == (10, 3) and not hasattr(m1, "omega") and not hasattr(m1, "t_log_scale")
    full = SpacetimeGaussians(ModelConfig(sh_degree=3), 10)
    assert full.motion.shape == (10, 9) and full.omega.shape == (10, 4) and full.sh_rest.shape == (10, 15, 3)
    assert full.t_center.shape == (10,) and full.t_log_scale.shape == (10,)
    assert not hasattr(SpacetimeGaussians(ModelConfig(), 10), "sh_rest")


@pytest.mark.parametrize("config", [ModelConfig(0, False, False, 0), ModelConfig()])
def test_static_at_is_identity_and_skips_time_terms(config, monkeypatch):
    m = random_model(40, config)
    m.set_dynamic(torch.zeros(40, dtype=torch.bool))

    def forbidden(*args, **kwargs):
        raise AssertionError("the time path ran for a static model")

    monkeypatch.setattr(SpacetimeGaussians, "_apply_time", forbidden)
    for t in (0.0, 0.5, 3.0):
        snap = m.at(t)
        assert snap.means is m.means and snap.quats is m.quats  # the Parameters themselves, no copy
        assert torch.equal(snap.opacities, torch.sigmoid(m.opacity_logits))
        assert torch.equal(snap.scales, torch.exp(m.log_scales))


def test_dynamic_index_set_only_touches_dynamic_rows(monkeypatch):
    m = random_model(100)
    mask = torch.zeros(100, dtype=torch.bool)
    mask[::10] = True
    m.set_dynamic(mask)
    seen = {}
    original = SpacetimeGaussians._apply_time

    def spy(self, t, idx, *rest):
        seen["rows"] = int(idx.numel())
        return original(self, t, idx, *rest)

    monkeypatch.setattr(SpacetimeGaussians, "_apply_time", spy)
    snap = m.at(0.4)
    assert seen["rows"] == 10
    ref = numpy_at(m, 0.4)
    dyn = mask.numpy()
    for f in ("means", "quats", "opacities"):
        got = getattr(snap, f).detach().numpy()
        np.testing.assert_allclose(got[dyn], ref[f][dyn], rtol=1e-5, atol=1e-6)
    np.testing.assert_array_equal(snap.means.detach().numpy()[~dyn], m.means.detach().numpy()[~dyn])
    np.testing.assert_array_equal(snap.opacities.detach().numpy()[~dyn],
                                  torch.sigmoid(m.opacity_logits).detach().numpy()[~dyn])


def test_static_dynamic_mix_equals_all_dynamic_when_time_params_vanish():
    t = 0.625
    m = random_model(80)
    static = torch.rand(80, generator=torch.Generator().manual_seed(3)) < 0.5
    with torch.no_grad():
        m.motion[static] = 0.0
        m.omega[static] = 0.0
        m.t_center[static] = t  # dt = 0: the temporal RBF is exactly 1
    mixed = SpacetimeGaussians.from_tensors(m.config, {**m.tensors(), "dynamic": ~static})
    everyone = SpacetimeGaussians.from_tensors(m.config, {**m.tensors(), "dynamic": torch.ones(80, dtype=torch.bool)})
    a, b = mixed.at(t), everyone.at(t)
    for f in FIELDS:
        assert torch.equal(getattr(a, f), getattr(b, f)), f


def test_dynamic_cache_follows_in_place_edits():
    m = random_model(30)
    m.set_dynamic(torch.zeros(30, dtype=torch.bool))
    assert torch.equal(m.at(0.9).means, m.means)
    m.dynamic[5] = True  # in place: the cached index set must notice
    assert m.num_dynamic == 1
    moved = (m.at(0.9).means - m.means).abs().sum(1) > 0
    assert moved.nonzero().flatten().tolist() == [5]


def test_gradients_reach_every_parameter():
    m = random_model(32, ModelConfig(sh_degree=2))
    snap = m.at(0.3, camera_center=np.array([0.2, -0.1, -3.0]))
    g = torch.Generator().manual_seed(1)
    loss = sum((getattr(snap, f) * torch.randn(getattr(snap, f).shape, generator=g)).sum() for f in FIELDS)
    loss.backward()
    for name in m.param_names():
        grad = getattr(m, name).grad
        assert grad is not None, name
        assert torch.isfinite(grad).all(), name
        assert grad.abs().sum() > 0, name
    frozen = m.snapshot(0.3)
    assert not frozen.means.requires_grad and torch.equal(frozen.means, snap.means.detach())


def test_time_gradients_match_finite_differences():
    m = random_model(6, dtype=torch.float64)

    def f(**override):
        for k, v in override.items():
            getattr(m, k).data.copy_(v)
        s = m.at(0.41)
        return (s.means.sum(1) * 0.3 + s.quats.sum(1) * 0.2 + s.opacities).sum()

    names = ["t_center", "t_log_scale", "motion", "omega"]
    base = {k: getattr(m, k).detach().clone() for k in names}
    m.zero_grad()
    f().backward()
    eps = 1e-6
    for k in names:
        analytic = getattr(m, k).grad.clone()
        flat = base[k].reshape(-1)
        for i in range(0, flat.numel(), max(1, flat.numel() // 5)):
            plus, minus = flat.clone(), flat.clone()
            plus[i] += eps
            minus[i] -= eps
            with torch.no_grad():
                fp = f(**{k: plus.view_as(base[k])}).item()
                fm = f(**{k: minus.view_as(base[k])}).item()
            getattr(m, k).data.copy_(base[k])
            assert analytic.reshape(-1)[i].item() == pytest.approx((fp - fm) / (2 * eps), rel=1e-5, abs=1e-8), (k, i)


@pytest.mark.parametrize("t", [-1.0, 0.0, 1.0, 1.5, 1e4])
def test_clip_ends_and_beyond_stay_finite(t):
    m = random_model(20)
    with torch.no_grad():
        m.t_log_scale[:5] = -200.0  # a vanishing temporal std would overflow exp(-s) without the clamp
        m.t_log_scale[5:10] = 50.0
    snap = m.at(t)
    loss = sum(getattr(snap, f).sum() for f in FIELDS)
    loss.backward()
    for f in FIELDS:
        assert torch.isfinite(getattr(snap, f)).all(), f
    for name in m.param_names():
        assert torch.isfinite(getattr(m, name).grad).all(), name
    assert (snap.opacities >= 0).all() and (snap.opacities <= 1).all()


def test_zero_quaternions_stay_finite():
    m = random_model(10, ModelConfig(sh_degree=1))
    with torch.no_grad():
        m.quats.zero_()
        m.omega.zero_()
    snap = m.at(0.2, camera_center=m.means[0].detach().numpy())  # also a Gaussian at the camera centre
    loss = sum(getattr(snap, f).sum() for f in FIELDS)
    loss.backward()
    assert torch.equal(snap.quats, torch.zeros(10, 4))
    for name in m.param_names():
        assert torch.isfinite(getattr(m, name).grad).all(), name


def test_view_dependent_colour_degree_one():
    m = SpacetimeGaussians(ModelConfig(0, False, False, sh_degree=1), 1)
    with torch.no_grad():
        m.means.copy_(torch.tensor([[0.0, 0.0, 5.0]]))
        m.colors.fill_(0.1)
        m.sh_rest[0, 1] = torch.tensor([1.0, 0.0, -1.0])  # the z-aligned band-1 function
    seen_from_origin = m.at(0.0, camera_center=np.zeros(3)).colors  # direction +z
    expected = torch.tensor([0.5 + SH_C0 * 0.1 + SH_C1, 0.5 + SH_C0 * 0.1, 0.5 + SH_C0 * 0.1 - SH_C1])
    torch.testing.assert_close(seen_from_origin[0], expected)
    assert torch.allclose(m.at(0.0).colors[0], torch.full((3,), 0.5 + SH_C0 * 0.1))  # no camera -> DC only
    behind = m.at(0.0, camera_center=np.array([0.0, 0.0, 10.0])).colors[0]  # direction -z
    assert behind[0] < expected[1] < expected[0]


def test_from_points_initialization():
    g = np.stack(np.meshgrid(*[np.arange(6) * 0.1] * 3, indexing="ij"), -1).reshape(-1, 3)
    times = np.repeat(np.array([0.0, 0.1, 0.2]), len(g) // 3 + 1)[: len(g)]
    colors = np.full((len(g), 3), 0.25)
    m = SpacetimeGaussians.from_points(g, colors, times, ModelConfig())
    assert m.num_gaussians == len(g) and bool(m.dynamic.all())
    interior = np.all((g > 0.05) & (g < 0.45), axis=1)
    np.testing.assert_allclose(torch.exp(m.log_scales).detach().numpy()[interior], 0.1, rtol=1e-5)
    np.testing.assert_allclose(torch.sigmoid(m.opacity_logits).detach().numpy(), 0.1, rtol=1e-5)
    np.testing.assert_allclose(m.at(0.0).colors.detach().numpy(), 0.25, atol=1e-6)
    np.testing.assert_array_equal(m.t_center.detach().numpy(), times.astype(np.float32))
    np.testing.assert_allclose(torch.exp(m.t_log_scale).detach().numpy(), 0.1, rtol=1e-5)  # one spacing
    assert torch.equal(m.quats.detach(), torch.tensor([1.0, 0, 0, 0]).expand(len(g), 4))
    assert not m.motion.detach().any() and not m.omega.detach().any()

    single_time = SpacetimeGaussians.from_points(g[:10], colors[:10], np.zeros(10), dynamic=np.zeros(10, bool))
    assert math.isclose(float(torch.exp(single_time.t_log_scale[0].detach())), 1.0, rel_tol=1e-6)
    assert single_time.num_dynamic == 0


def test_knn_scales_degenerate_clouds():
    assert knn_scales(np.zeros((0, 3))).shape == (0,)
    assert knn_scales(np.zeros((1, 3)))[0] > 0
    dup = knn_scales(np.zeros((5, 3)))
    assert np.all(dup > 0) and np.all(np.isfinite(dup))
    np.testing.assert_allclose(knn_scales(np.array([[0.0, 0, 0], [0.5, 0, 0]])), 0.5)


def test_from_points_rejects_bad_input():
    with pytest.raises(InputError, match="times"):
        SpacetimeGaussians.from_points(np.zeros((3, 3)), np.zeros((3, 3)), np.zeros(2))
    with pytest.raises(InputError, match="points"):
        SpacetimeGaussians.from_points(np.full((3, 3), np.nan), np.zeros((3, 3)), np.zeros(3))
    with pytest.raises(InputError, match="motion_degree"):
        ModelConfig(motion_degree=4)


def test_prune_append_and_param_groups():
    m = random_model(10, ModelConfig(sh_degree=1))
    keep = torch.zeros(10, dtype=torch.bool)
    keep[[1, 4, 7]] = True
    before = {k: v.clone() for k, v in m.tensors().items()}
    m.prune(keep)
    assert m.num_gaussians == 3
    for k, v in m.tensors().items():
        assert torch.equal(v, before[k][keep]), k
    extra = {k: before[k][:2] for k in m.param_names()}
    m.append({**extra, "dynamic": torch.tensor([False, True])})
    assert m.num_gaussians == 5 and m.dynamic.tolist() == [keep[1].item(), keep[4].item(), keep[7].item(),
                                                             False, True]
    assert torch.equal(m.means[3:], before["means"][:2])
    assert all(isinstance(getattr(m, k), torch.nn.Parameter) for k in m.param_names())
    with pytest.raises(InputError, match="missing"):
        m.append({"means": torch.zeros(1, 3)})
    lrs = {k: 0.01 * (i + 1) for i, k in enumerate(m.param_names())}
    groups = m.param_groups({**lrs, "unused": 1.0})
    assert [g["name"] for g in groups] == m.param_names()
    assert all(g["params"][0] is getattr(m, g["name"]) and g["lr"] == lrs[g["name"]] for g in groups)
    torch.optim.Adam(groups)  # accepted as is
    with pytest.raises(InputError, match="learning rate"):
        m.param_groups({"means": 1.0})


def test_state_dict_round_trip_any_size():
    m = random_model(12, ModelConfig(motion_degree=2, sh_degree=1))
    m.set_dynamic(torch.arange(12) % 3 == 0)
    back = SpacetimeGaussians.from_state_dict(m.state_dict(), m.config)
    for k, v in m.tensors().items():
        assert torch.equal(v, back.tensors()[k]), k
