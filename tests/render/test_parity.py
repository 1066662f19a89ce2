"""Fast kernel (numba, float32) against the oracle (torch, float32): values and gradients.

The cpu row of the parity table in docs/render.md (the rendering contract); its tolerances are
the constants below.
"""
from __future__ import annotations

import numpy as np
import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fixer4d.geometry.camera import Camera
from fixer4d.model.snapshot import Snapshot
from fixer4d.render.api import render
from fixer4d.render.constants import NEAR_PLANE

from .scenes import FIELDS, front_camera, leaf, loss_weights, random_snapshot, weighted_loss

VALUE_TOL = 1e-4  # rgb/alpha absolute; depth relative to its magnitude
GRAD_RTOL = 1e-3  # norm-relative, per field
GRAD_ATOL = 1e-5  # for fields whose gradient is (almost) zero everywhere


def _both(snap: Snapshot, cam: Camera, background=(0.2, 0.4, 0.6)):
    """Render with both backends; return {backend: (out, leaf snapshot with grads)}."""
    weights = loss_weights(cam.height, cam.width, torch.float32, seed=11)
    res = {}
    for backend in ("cpu", "reference"):
        s = leaf(snap)
        out = render(s, cam, background=background, backend=backend)
        weighted_loss(out, weights).backward()
        res[backend] = (out, s)
    return res


def assert_parity(snap: Snapshot, cam: Camera, grad_slack: dict[str, float] | None = None) -> None:
    """Values, fragment counts and radii as the float32 oracle's; gradients within GRAD_RTOL
    (norm-relative) plus ``grad_slack[field]`` (absolute, for gradients whose float32 value is
    mostly round-off: see test_long_splats)."""
    grad_slack = grad_slack or {}
    res = _both(snap.to(dtype=torch.float32), cam)
    (fast, sf), (ref, sr) = res["cpu"], res["reference"]
    assert fast.backend == "cpu" and ref.backend == "reference"
    for name in ("rgb", "alpha", "depth"):
        a, b = getattr(fast, name).detach(), getattr(ref, name).detach()
        assert torch.isfinite(a).all() and torch.isfinite(b).all(), name
        tol = VALUE_TOL * (1.0 + b.abs()) if name == "depth" else VALUE_TOL
        assert ((a - b).abs() <= tol).all(), (name, float((a - b).abs().max()))
    assert fast.n_fragments == ref.n_fragments
    assert torch.equal(fast.radii, ref.radii)
    pairs = [(getattr(sf, f).grad, getattr(sr, f).grad, f) for f in FIELDS]
    pairs.append((fast.means2d.grad, ref.means2d.grad, "means2d"))
    for a, b, name in pairs:
        assert a is not None and b is not None, name
        assert torch.isfinite(a).all() and torch.isfinite(b).all(), name
        err, scale = float((a - b).norm()), float(b.norm())
        assert err <= GRAD_RTOL * scale + GRAD_ATOL + grad_slack.get(name, 0.0), (name, err, scale)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_parity_random_scenes(seed):
    snap = random_snapshot(300, seed=seed, dtype=torch.float32, spread=1.0, scale_range=(0.01, 0.15))
    assert_parity(snap, front_camera(48, 36))


def test_parity_dense_opaque_scene_with_early_stop():
    snap = random_snapshot(400, seed=7, dtype=torch.float32, spread=0.5, scale_range=(0.05, 0.3),
                           opacity_range=(0.5, 1.0))
    cam = front_camera(40, 30)
    assert_parity(snap, cam)
    out = render(snap, cam, backend="cpu")
    # the early stop is exercised: opaque pixels end with T below 1/100 but not below T_MIN
    assert float(out.alpha.max()) > 0.99


def test_parity_non_square_offcentre_camera():
    K = np.array([[30.0, 0.0, 9.0], [0.0, 36.0, 20.0], [0.0, 0.0, 1.0]])
    base = front_camera(33, 17)
    cam = Camera(K, base.c2w, 33, 17, "off")
    assert_parity(random_snapshot(150, seed=5, dtype=torch.float32, scale_range=(0.02, 0.2)), cam)


# ---- hard cases ------------------------------------------------------------------------------
CAM_DIST = 4.0  # front_camera sits at z = -4 looking at +z: camera-frame z = world z + 4

KINDS = ("normal", "tiny", "huge", "behind", "near_plane", "at_camera", "off_screen", "elongated",
         "opacity0", "opacity1", "zero_quat", "one_pixel")


def _hard_gaussian(kind: str, rng: np.random.Generator):
    mean = rng.uniform(-0.8, 0.8, 3)
    quat = rng.normal(size=4)
    scale = rng.uniform(0.05, 0.3, 3)
    opacity = rng.uniform(0.2, 0.9)
    if kind == "tiny":
        scale = np.full(3, 1e-6)
    elif kind == "huge":
        scale = rng.uniform(1e2, 1e3, 3)
    elif kind == "behind":
        mean[2] = -CAM_DIST - rng.uniform(0.1, 3.0)
    elif kind == "near_plane":
        mean[2] = -CAM_DIST + NEAR_PLANE * rng.choice([0.999, 1.0, 1.001, 1.5])
    elif kind == "at_camera":
        mean = np.array([0.0, 0.0, -CAM_DIST])
    elif kind == "off_screen":
        mean[0] = rng.choice([-1.0, 1.0]) * rng.uniform(5.0, 50.0)
    elif kind == "elongated":
        scale = np.array([1e-4, rng.uniform(0.5, 2.0), 1e-4])
    elif kind == "opacity0":
        opacity = 0.0
    elif kind == "opacity1":
        opacity = 1.0
    elif kind == "zero_quat":
        quat = np.zeros(4)
    elif kind == "one_pixel":
        mean = np.array([0.0, 0.0, 0.0])
        scale = np.full(3, 0.02)
    return mean, quat, scale, opacity


def hard_snapshot(kinds: list[str], seed: int) -> Snapshot:
    rng = np.random.default_rng(seed)
    rows = [_hard_gaussian(k, rng) for k in kinds]
    if not rows:
        return Snapshot(torch.zeros(0, 3), torch.zeros(0, 4), torch.zeros(0, 3), torch.zeros(0), torch.zeros(0, 3))
    f = lambda i: torch.tensor(np.array([r[i] for r in rows]), dtype=torch.float32)  # noqa: E731
    return Snapshot(f(0), f(1), f(2), f(3), torch.tensor(rng.uniform(0, 1, (len(rows), 3)), dtype=torch.float32))


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(kinds=st.lists(st.sampled_from(KINDS), min_size=0, max_size=14),
       size=st.sampled_from([(1, 1), (7, 5), (16, 12)]), seed=st.integers(0, 2 ** 16))
def test_hard_cases_finite_and_in_parity(kinds, size, seed):
    assert_parity(hard_snapshot(kinds, seed), front_camera(*size))


def test_many_gaussians_in_one_pixel():
    kinds = ["one_pixel"] * 300
    snap = hard_snapshot(kinds, 0)
    snap.opacities = torch.full((300,), 0.5)
    assert_parity(snap, front_camera(9, 9))
    # 1x1 image: all 300 sit on the pixel centre (alpha = 0.5 each); the walk blends 13 of them
    # (T = 0.5^13 = 1.2e-4) and stops before the 14th (0.5^14 = 6.1e-5 < T_MIN)
    cam = front_camera(1, 1)
    assert_parity(snap, cam)
    for backend in ("cpu", "reference"):
        out = render(snap, cam, backend=backend)
        assert out.n_fragments == 13
        assert abs(float(out.alpha[0, 0]) - (1 - 0.5 ** 13)) < 1e-6
