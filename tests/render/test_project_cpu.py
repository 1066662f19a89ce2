"""The numba projection (project_cpu.py, hand-written backward) against the readable torch
projection (project.py, autograd): values, radii and gradients, ordinary and culled cases.

The cpu row of the parity table in docs/render.md (the rendering contract).
"""
from __future__ import annotations

import pytest
import torch

from fixer4d.model.snapshot import Snapshot
from fixer4d.render import project_cpu
from fixer4d.render.project import project_gaussians
from fixer4d.render.project_cpu import project_gaussians_cpu

from .scenes import front_camera, leaf, random_snapshot

pytestmark = pytest.mark.skipif(project_cpu.unavailable_reason() is not None, reason="numba missing")

OUTPUTS = ("means2d", "conic_ldl", "depths")


def hard_snapshot(dtype) -> Snapshot:
    """Random Gaussians plus the cases with their own branches: behind the camera, on and just
    past the near plane (z = 0.01 at camera distance 4), far off-screen (tangent clamp active),
    a zero and a non-finite-norm-free tiny quaternion, tiny and huge scales, a needle."""
    base = random_snapshot(200, seed=4, dtype=torch.float64, spread=1.5, scale_range=(0.01, 0.4))
    means = torch.tensor([[0.1, 0.2, -5.0], [0.0, 0.0, -3.99], [0.05, 0.0, -3.98], [40.0, -3.0, 1.0],
                          [-2.0, 30.0, 2.0], [0.2, 0.1, 0.0], [0.3, -0.2, 0.5], [-0.1, 0.1, 0.2],
                          [0.0, 0.3, -0.5]], dtype=torch.float64)
    quats = torch.tensor([[1.0, 0, 0, 0], [0.3, 0.1, -0.2, 0.9], [0.5, 0.5, 0.5, 0.5], [0.2, -0.7, 0.1, 0.3],
                          [0.9, 0.1, 0.3, -0.2], [0.0, 0.0, 0.0, 0.0], [1e-14, 0, 0, 0], [0.7, 0.1, 0.6, 0.2],
                          [0.96, 0.0, 0.28, 0.0]], dtype=torch.float64)
    scales = torch.tensor([[0.1, 0.2, 0.1], [0.05, 0.05, 0.05], [0.2, 0.1, 0.3], [0.5, 0.2, 0.1],
                           [0.3, 0.3, 0.3], [0.1, 0.1, 0.1], [1e-6, 1e-6, 1e-6], [1e3, 1e-3, 1e-3],
                           [50.0, 1e-3, 1e-3]], dtype=torch.float64)
    k = means.shape[0]
    snap = Snapshot(torch.cat([base.means, means]), torch.cat([base.quats, quats]),
                    torch.cat([base.scales, scales]), torch.cat([base.opacities, torch.full((k,), 0.5, dtype=torch.float64)]),
                    torch.cat([base.colors, torch.full((k, 3), 0.5, dtype=torch.float64)]))
    return snap.to(dtype=dtype)


def _grads(fn, snap, weights):
    s = leaf(snap)
    proj = fn(s, front_camera(64, 48))
    loss = sum((getattr(proj, name) * w).sum() for name, w in zip(OUTPUTS, weights))
    loss.backward()
    return proj, {f: getattr(s, f).grad for f in ("means", "quats", "scales")}


def _weights(snap, seed=0):
    g = torch.Generator().manual_seed(seed)
    n, dt = len(snap), snap.means.dtype
    return [torch.randn(n, 2, generator=g, dtype=dt), torch.randn(n, 3, generator=g, dtype=dt),
            torch.randn(n, generator=g, dtype=dt)]


def test_float64_matches_torch_autograd():
    snap = hard_snapshot(torch.float64)
    w = _weights(snap)
    ref, g_ref = _grads(project_gaussians, snap, w)
    got, g_got = _grads(project_gaussians_cpu, snap, w)
    assert torch.equal(got.radii, ref.radii)
    assert (ref.radii == 0).sum() >= 4 and (ref.radii > 3000).any()  # culled cases and a needle are in
    for name in OUTPUTS:
        a, b = getattr(got, name), getattr(ref, name)
        assert torch.allclose(a, b, rtol=1e-12, atol=1e-12), name
    for f in g_ref:
        assert torch.isfinite(g_got[f]).all(), f
        assert torch.allclose(g_got[f], g_ref[f], rtol=1e-9, atol=1e-9 * float(g_ref[f].abs().max())), f


def test_float32_matches_torch_float32():
    """float32, as the cpu backend runs it: values to a few ulp, radii identical, gradients to
    float32 round-off."""
    snap = hard_snapshot(torch.float32)
    w = _weights(snap, seed=1)
    ref, g_ref = _grads(project_gaussians, snap, w)
    got, g_got = _grads(project_gaussians_cpu, snap, w)
    assert got.means2d.dtype == torch.float32 and got.radii.dtype == torch.int32
    assert torch.equal(got.radii, ref.radii)
    for name in OUTPUTS:
        a, b = getattr(got, name), getattr(ref, name)
        assert torch.allclose(a, b, rtol=1e-5, atol=1e-6), (name, float((a - b).abs().max()))
    for f in g_ref:
        err, scale = float((g_got[f] - g_ref[f]).norm()), float(g_ref[f].norm())
        assert err <= 1e-4 * scale, (f, err, scale)


def test_empty_snapshot():
    snap = random_snapshot(0, dtype=torch.float32)
    proj = project_gaussians_cpu(snap, front_camera())
    assert proj.means2d.shape == (0, 2) and proj.conic_ldl.shape == (0, 3) and proj.radii.shape == (0,)
