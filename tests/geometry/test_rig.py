"""The rig's own cues: focus point, convergence, common view (frustum overlap)."""
from __future__ import annotations

import numpy as np
import pytest

from fixer4d.errors import InputError
from fixer4d.geometry.camera import Camera
from fixer4d.geometry.rig import axes_converge, common_view_bounds, rig_focus


def _ring(n=4, radius=3.0, target=(0.2, 0.5, -0.1), arc_deg=90.0):
    K = Camera.intrinsics_from_fov(np.radians(50.0), 64, 48)
    angles = np.radians(np.linspace(-arc_deg / 2, arc_deg / 2, n))
    t = np.asarray(target)
    return [Camera.look_at(t + radius * np.array([np.sin(a), 0.3, np.cos(a)]), t, K=K, width=64, height=48)
            for a in angles]


def _parallel(n=4, spacing=0.3):
    K = Camera.intrinsics_from_fov(np.radians(45.0), 80, 60)
    return [Camera.look_at(np.array([x, 1.0, 4.0]), np.array([x, 1.0, 0.0]), K=K, width=80, height=60)
            for x in (np.arange(n) - (n - 1) / 2) * spacing]


def _visible_by_all(cams, pts):
    ok = np.ones(len(pts), bool)
    for c in cams:
        uv, z = c.project(pts)
        with np.errstate(invalid="ignore"):
            ok &= (z > 0) & (uv[:, 0] >= 0) & (uv[:, 0] <= c.width) & (uv[:, 1] >= 0) & (uv[:, 1] <= c.height)
    return ok


def test_focus_of_a_converging_rig_is_the_target():
    cams = _ring()
    assert axes_converge(cams)
    np.testing.assert_allclose(rig_focus(cams), [0.2, 0.5, -0.1], atol=1e-9)


def test_parallel_rig_does_not_converge_and_focus_falls_back():
    cams = _parallel()
    assert not axes_converge(cams)
    np.testing.assert_allclose(rig_focus(cams, fallback=np.array([1.0, 2.0, 3.0])), [1.0, 2.0, 3.0])
    f = rig_focus(cams)
    # The common view's centre: on the rig's axis, in front of every camera.
    assert abs(f[0]) < 1e-6 and all(c.world_to_camera(f[None])[0, 2] > 0 for c in cams)


def test_common_view_holds_what_every_camera_sees_and_nothing_else():
    cams = _ring()
    vb = common_view_bounds(cams)
    focus = np.array([0.2, 0.5, -0.1])
    assert np.all(vb.bbox_min < focus) and np.all(focus < vb.bbox_max)
    # Points all cameras see lie in the box; most of the box's corners region is seen by none.
    rng = np.random.default_rng(0)
    pts = focus + rng.uniform(-4, 4, (20000, 3))
    seen = _visible_by_all(cams, pts)
    inside = np.all((pts >= vb.bbox_min - 1e-6) & (pts <= vb.bbox_max + 1e-6), 1)
    assert seen.any() and inside[seen].mean() > 0.97
    for (near, far), c in zip(vb.depth_ranges, cams):
        z = c.world_to_camera(pts[seen])[:, 2]
        assert near <= np.quantile(z, 0.01) and np.quantile(z, 0.99) <= far * 1.01
    assert vb.near == min(r[0] for r in vb.depth_ranges) and vb.far == max(r[1] for r in vb.depth_ranges)


def test_parallel_rig_common_view_starts_where_the_frusta_overlap():
    cams = _parallel(n=4, spacing=0.3)
    vb = common_view_bounds(cams)
    # Outer cameras 0.9 apart, half-width tan(fov_x / 2) z: overlap from z = 0.9 / (2 tan(fov_x / 2)).
    z0 = 0.9 / (2 * np.tan(cams[0].fov_x / 2))
    near = vb.depth_ranges[0][0]
    assert z0 <= near <= 1.1 * z0


def test_disjoint_cameras_have_no_common_view():
    K = Camera.intrinsics_from_fov(np.radians(40.0), 32, 32)
    cams = [Camera.look_at(np.array([0.0, 0.0, 0.0]), np.array([0.0, 0.0, 1.0]), K=K, width=32, height=32),
            Camera.look_at(np.array([0.0, 0.0, 0.0]), np.array([0.0, 0.0, -1.0]), K=K, width=32, height=32)]
    with pytest.raises(InputError, match="common view"):
        common_view_bounds(cams)
