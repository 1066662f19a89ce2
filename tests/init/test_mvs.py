import numpy as np
import pytest

from fixer4d.errors import BackendUnavailable, InputError
from fixer4d.init.mvs import (DepthEstimator, MVSAnywhereEstimator, PlaneSweepConfig, PlaneSweepMVS,
                              default_depth_ranges, depth_ranges_from_points, make_estimator)
from planescene import PLANE_Z, plane_cameras, render_plane


@pytest.fixture(scope="module")
def plane_result():
    cams = plane_cameras()
    images = [render_plane(c)[0] for c in cams]
    est = PlaneSweepMVS(PlaneSweepConfig(planes=48))
    return cams, est.estimate(images, cams, [(2.0, 8.0)] * 4)


def test_planesweep_is_a_depth_estimator():
    assert isinstance(PlaneSweepMVS(), DepthEstimator)


def test_fronto_parallel_plane_within_one_percent(plane_result):
    cams, results = plane_result
    for cam, res in zip(cams, results):
        assert res.depth.shape == (cam.height, cam.width)
        assert res.valid.mean() > 0.6, "most textured pixels should get a depth"
        rel = np.abs(res.depth - PLANE_Z) / PLANE_Z
        # a half-pixel slip in the warp would bias depth by ~4-7% at these disparities (7-14 px)
        assert np.median(rel[res.valid]) < 0.003
        assert np.mean(rel[res.valid] < 0.01) > 0.9
        confident = res.valid & (res.confidence > 0.5)
        assert confident.mean() > 0.5 and np.mean(rel[confident] < 0.01) > 0.93
        assert np.all(res.depth[~res.valid] == 0)
        assert np.all((res.confidence >= 0) & (res.confidence <= 1))


def test_scale_halves_resolution():
    cams = plane_cameras()
    images = [render_plane(c)[0] for c in cams]
    res = PlaneSweepMVS(PlaneSweepConfig(planes=32, scale=0.5)).estimate(images, cams, [(2.0, 8.0)] * 4)
    assert res[0].depth.shape == (36, 48) and res[0].camera.width == 48
    rel = np.abs(res[0].depth[res[0].valid] - PLANE_Z) / PLANE_Z
    assert res[0].valid.mean() > 0.4 and np.median(rel) < 0.01


def test_textureless_views_give_no_valid_depth():
    cams = plane_cameras(48, 36)
    images = [render_plane(c, textured=False)[0] for c in cams]
    res = PlaneSweepMVS(PlaneSweepConfig(planes=16)).estimate(images, cams, [(2.0, 8.0)] * 4)
    assert all(not r.valid.any() for r in res)
    assert all(np.all(np.isfinite(r.depth)) for r in res)


def test_bad_inputs_raise_clear_errors():
    cams = plane_cameras(48, 36)
    images = [render_plane(c)[0] for c in cams]
    est = PlaneSweepMVS(PlaneSweepConfig(planes=8))
    with pytest.raises(InputError, match="at least 2 views"):
        est.estimate(images[:1], cams[:1])
    with pytest.raises(InputError, match="resize"):
        est.estimate([images[0][:30]] + images[1:], cams)
    with pytest.raises(InputError, match="near < far"):
        est.estimate(images, cams, [(5.0, 2.0)] * 4)
    with pytest.raises(InputError, match="planes"):
        PlaneSweepMVS(PlaneSweepConfig(planes=1))


def test_depth_ranges_cover_the_plane():
    cams = plane_cameras()
    pts = np.array([[x, y, PLANE_Z] for x in np.linspace(-1, 1, 5) for y in np.linspace(-1, 1, 5)])
    for near, far in depth_ranges_from_points(pts, cams):
        assert near < PLANE_Z < far
    # parallel axes: no convergence point, a range from the rig radius
    for near, far in default_depth_ranges(cams):
        assert 0 < near < far


def test_mvsanywhere_missing_names_what_is_missing(monkeypatch, tmp_path):
    monkeypatch.delenv("FIXER4D_MVSANYWHERE_WEIGHTS", raising=False)
    monkeypatch.delenv("FIXER4D_MVSANYWHERE_CONFIG", raising=False)
    with pytest.raises(BackendUnavailable) as exc:
        make_estimator("mvsanywhere")
    msg = str(exc.value)
    assert "mvsanywhere" in msg and "FIXER4D_MVSANYWHERE_WEIGHTS" in msg and "planesweep" in msg
    monkeypatch.setenv("FIXER4D_MVSANYWHERE_WEIGHTS", str(tmp_path / "nope.ckpt"))
    with pytest.raises(BackendUnavailable, match="nope.ckpt"):
        MVSAnywhereEstimator()
    with pytest.raises(InputError, match="unknown depth estimator"):
        make_estimator("magic")
