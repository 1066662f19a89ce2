"""Clone/split/prune keep the model and Adam's state aligned: survivors carry their moments,
new Gaussians start at zero, the cap holds, split children shrink by 1.6."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from fixer4d.model.densify import DensifyStats, densify_and_prune, prune_gaussians, quat_to_matrix
from fixer4d.model.spacetime import ModelConfig, SpacetimeGaussians

EXTENT = 2.0
SMALL, LARGE, HUGE = 0.01, 0.1, 1.0  # world std devs vs percent_dense * EXTENT = 0.02, 0.1 * EXTENT = 0.2


def _setup():
    """6 Gaussians: 0 hot+small (clone), 1 hot+large (split), 2 cold, 3 transparent (prune),
    4 huge (prune), 5 cold; an Adam with populated moments."""
    pts = np.arange(18, dtype=np.float64).reshape(6, 3)
    scales = np.array([SMALL, LARGE, SMALL, SMALL, HUGE, SMALL])
    model = SpacetimeGaussians.from_points(pts, np.full((6, 3), 0.5), np.linspace(0, 0.5, 6),
                                           ModelConfig(), opacity=0.5, scales=scales)
    with torch.no_grad():
        model.opacity_logits[3] = math.log(0.001 / 0.999)
        model.quats[1] = torch.tensor([0.9, 0.1, 0.3, -0.2])
    lrs = dict.fromkeys(["means", "log_scales", "quats", "opacity_logits", "colors", "sh_rest", "t_center",
                         "t_log_scale", "motion", "omega"], 1e-3)
    opt = torch.optim.Adam(model.param_groups(lrs), eps=1e-15)
    g = torch.Generator().manual_seed(0)
    for p in model.parameters():
        p.grad = torch.randn(p.shape, generator=g)
    opt.step()
    stats = DensifyStats.zeros(6)
    stats.grad_accum[:] = torch.tensor([1.0, 1.0, 0.0, 0.0, 0.0, 0.0])
    stats.denom[:] = 1.0
    return model, opt, stats


def _run(model, opt, stats, **kw):
    args = dict(extent=EXTENT, grad_threshold=0.5, percent_dense=0.01, max_gaussians=100, prune_opacity=0.005,
                prune_world_scale=0.1, prune_screen_fraction=None, generator=torch.Generator().manual_seed(1))
    args.update(kw)
    return densify_and_prune(model, opt, stats, **args)


def test_clone_split_prune_counts_and_values():
    model, opt, stats = _setup()
    old = {k: v.detach().clone() for k, v in model.named_parameters()}
    counts = _run(model, opt, stats)
    assert counts["cloned"] == 1 and counts["split"] == 1
    # 6 + 1 clone + 2 children - split parent - transparent - huge = 6
    assert model.num_gaussians == 6
    # survivors in order: 0, 2, 5, then the clone of 0, then the two children of 1
    assert torch.equal(model.means[:3], old["means"][[0, 2, 5]])
    assert torch.equal(model.means[3], old["means"][0])
    children = model.means[4:].detach()
    assert not torch.equal(children[0], children[1])
    assert torch.allclose(torch.exp(model.log_scales[4:]), torch.exp(old["log_scales"][[1, 1]]) / 1.6)
    assert torch.equal(model.t_center[4:], old["t_center"][[1, 1]])
    assert model.dynamic.shape == (6,)


def test_adam_state_follows_the_gaussians():
    model, opt, stats = _setup()
    before = {g["name"]: {k: opt.state[g["params"][0]][k].clone() for k in ("exp_avg", "exp_avg_sq")}
              for g in opt.param_groups}
    _run(model, opt, stats)
    params = dict(model.named_parameters())
    for g in opt.param_groups:
        p = g["params"][0]
        assert p is params[g["name"]]  # the group points at the model's current Parameter
        st = opt.state[p]
        for k in ("exp_avg", "exp_avg_sq"):
            assert st[k].shape == p.shape
            assert torch.equal(st[k][:3], before[g["name"]][k][[0, 2, 5]])  # carried for survivors
            assert torch.count_nonzero(st[k][3:]) == 0  # zero for new Gaussians
    # the optimizer still steps the new Parameters
    for p in model.parameters():
        p.grad = torch.ones_like(p)
    means = model.means.detach().clone()
    opt.step()
    assert not torch.equal(means, model.means.detach())


def test_cap_limits_growth_to_the_hottest():
    model, opt, stats = _setup()
    stats.grad_accum[:] = torch.tensor([2.0, 1.0, 0.0, 0.0, 0.0, 0.0])
    counts = _run(model, opt, stats, max_gaussians=7)
    assert counts["cloned"] == 1 and counts["split"] == 0  # budget 1: only the hotter clone fits
    counts = _run(model, opt, DensifyStats.zeros(model.num_gaussians), max_gaussians=model.num_gaussians)
    assert counts["cloned"] == counts["split"] == 0


def test_size_pruning_only_when_enabled():
    model, opt, stats = _setup()
    stats.grad_accum.zero_()
    _run(model, opt, stats, prune_world_scale=None)
    assert model.num_gaussians == 5  # only the transparent one
    stats = DensifyStats.zeros(5)
    stats.max_radii[0] = 0.5
    _run(model, opt, stats, prune_world_scale=None, prune_screen_fraction=0.1)
    assert model.num_gaussians == 4


def test_never_prunes_to_empty():
    model, opt, _ = _setup()
    with torch.no_grad():
        model.opacity_logits.fill_(-20.0)
    _run(model, opt, DensifyStats.zeros(6))
    assert model.num_gaussians == 1


def test_prune_gaussians_plain():
    model, opt, _ = _setup()
    keep = torch.tensor([True, False, True, False, True, True])
    prune_gaussians(model, opt, keep)
    assert model.num_gaussians == 4
    for g in opt.param_groups:
        assert opt.state[g["params"][0]]["exp_avg"].shape[0] == 4


def test_stats_use_ndc_gradients_of_drawn_gaussians_only():
    stats = DensifyStats.zeros(3)
    grad = torch.tensor([[1.0, 0.0], [0.0, 2.0], [5.0, 5.0]])
    radii = torch.tensor([4, 2, 0], dtype=torch.int32)
    stats.update(grad, radii, width=20, height=10)
    stats.update(grad, radii, width=20, height=10)
    assert torch.allclose(stats.mean_grad(), torch.tensor([10.0, 10.0, 0.0]))  # x*W/2, y*H/2
    assert torch.equal(stats.denom, torch.tensor([2.0, 2.0, 0.0]))
    assert torch.allclose(stats.max_radii, torch.tensor([0.2, 0.1, 0.0]))


def test_quat_to_matrix_is_a_rotation_and_zero_is_identity():
    q = torch.tensor([[0.0, 0.0, 0.0, 0.0], [1.0, 2.0, -1.0, 0.5]])
    R = quat_to_matrix(q)
    assert torch.allclose(R[0], torch.eye(3))
    assert torch.allclose(R[1] @ R[1].T, torch.eye(3), atol=1e-6)
    assert float(torch.det(R[1])) == pytest.approx(1.0, abs=1e-6)


def test_frozen_rows_are_never_cloned_split_or_pruned():
    """Rows 0 (hot, small), 1 (hot, large), 3 (transparent) and 4 (huge) frozen: none of the
    clone/split/prune that _setup's counts show happens to them, and they stay in place."""
    model, opt, stats = _setup()
    frozen = torch.tensor([True, True, False, True, True, False])
    model.set_frozen(frozen)
    old = model.means.detach().clone()
    counts = _run(model, opt, stats)
    assert counts == {"cloned": 0, "split": 0, "pruned": 0, "total": 6}
    assert torch.equal(model.means, old) and torch.equal(model.frozen, frozen)


def test_appended_and_pruned_rows_keep_the_frozen_flags():
    model, opt, stats = _setup()
    model.set_frozen(torch.tensor([False, False, True, False, False, True]))
    _run(model, opt, stats)  # clone of 0 and split of 1 are appended unfrozen; 3 and 4 pruned
    assert model.frozen.tolist() == [False, True, True, False, False, False]
