import numpy as np
import pytest

from fixer4d.errors import BackendUnavailable, InputError
from fixer4d.init.depth_estimator import DepthEstimator
from fixer4d.init.depth_range import default_depth_ranges, depth_ranges_from_points
from fixer4d.init.mvs import make_estimator
from fixer4d.init.mvsanywhere import MVSAnywhereEstimator
from fixer4d.init.plane_sweep import PlaneSweepConfig, PlaneSweepMVS
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


# ---- coarse-to-fine sweep, regions, box filter ---------------------------------------------------
@pytest.fixture(scope="module")
def toy_views():
    """Four views of the toy scene (wall, slanted floor, sphere in front: depth edges) + true depth."""
    from toyscene import render, rig

    cams = rig(160, 120)[:4]
    images, depths = zip(*[render(c, 0.0) for c in cams])
    return list(images), list(depths), cams


def test_coarse_to_fine_agrees_with_the_full_sweep(toy_views):
    images, depths, cams = toy_views
    ranges = [(1.5, 8.0)] * 4
    full = PlaneSweepMVS(PlaneSweepConfig(planes=64, refine_band=0)).estimate(images, cams, ranges)
    c2f = PlaneSweepMVS(PlaneSweepConfig(planes=64)).estimate(images, cams, ranges)
    assert PlaneSweepConfig(planes=64).coarse_to_fine and not PlaneSweepConfig(planes=64, refine_band=0).coarse_to_fine
    for f, c, gt in zip(full, c2f, depths):
        good_f = f.valid & (np.abs(f.depth - gt) < 0.02 * gt)
        good_c = c.valid & (np.abs(c.depth - gt) < 0.02 * gt)
        # measured: the coarse-to-fine sweep keeps 99.2-99.7% of the full sweep's good depths
        assert good_c.sum() >= 0.97 * good_f.sum(), (good_c.sum(), good_f.sum())
        both = f.valid & c.valid
        # where both find a depth it is the same plane: the fine level's scores are the full
        # sweep's (fronto-parallel planes, windows inside their tile's margin); measured 99.8-99.99%
        assert np.mean(np.abs(f.depth[both] - c.depth[both]) <= 1e-3 * f.depth[both]) > 0.99
        assert np.all(c.depth[~c.valid] == 0)


def test_coarse_to_fine_on_a_plane_matches_the_full_sweep(plane_result):
    cams, full = plane_result
    images = [render_plane(c)[0] for c in cams]
    c2f = PlaneSweepMVS(PlaneSweepConfig(planes=48)).estimate(images, cams, [(2.0, 8.0)] * 4)
    for a, b in zip(full, c2f):
        assert abs(int(a.valid.sum()) - int(b.valid.sum())) <= 0.02 * a.valid.sum()
        both = a.valid & b.valid
        assert np.allclose(a.depth[both], b.depth[both], rtol=1e-4)


def test_region_sweep_matches_the_whole_frame_inside_the_region(toy_views):
    images, _, cams = toy_views
    ranges = [(1.5, 8.0)] * 4
    est = PlaneSweepMVS(PlaneSweepConfig(planes=64))
    whole = est.estimate(images, cams, ranges)
    roi = np.zeros((120, 160), bool)
    roi[40:80, 50:110] = True
    part = est.estimate(images, cams, ranges, rois=[roi, roi, roi, None], roi_margin=8)
    assert not part[3].valid.any(), "a view without a region is only a source"
    for w, p in zip(whole[:3], part[:3]):
        outside = np.ones_like(roi)
        outside[32:88, 42:118] = False  # the region widened by the 8 px margin: the swept box
        assert not p.valid[outside].any()
        inner = np.zeros_like(roi)
        inner[48:72, 58:102] = True  # the region less the window margin
        both = w.valid & p.valid & inner
        # measured: 83-98% of the whole-frame depths there, every one the same (the coarse level
        # sees less context in the box)
        assert both.sum() > 0.75 * (w.valid & inner).sum()
        assert np.mean(np.abs(w.depth[both] - p.depth[both]) <= 1e-3 * w.depth[both]) > 0.99


def test_box_filter_is_the_border_shrinking_mean():
    import torch
    import torch.nn.functional as F

    from fixer4d.init.matching_cost import _box

    rng = np.random.default_rng(0)
    for shape, k in [((2, 3, 17, 23), 7), ((1, 1, 5, 4), 7), ((3, 2, 9, 9), 3)]:
        x = torch.from_numpy(rng.random(shape).astype(np.float32))
        ref = F.avg_pool2d(x, k, stride=1, padding=k // 2, count_include_pad=False) if min(shape[2:]) > k // 2 else None
        if ref is not None:
            assert torch.allclose(_box(x, k), ref, atol=1e-6)
        # brute force on the small ones
        H, W = shape[2:]
        r = k // 2
        brute = np.stack([[x[..., max(i - r, 0):i + r + 1, max(j - r, 0):j + r + 1].mean((-1, -2)).numpy()
                           for j in range(W)] for i in range(H)])
        assert np.allclose(_box(x, k).numpy(), np.moveaxis(brute, (0, 1), (-2, -1)), atol=1e-6)


def test_tile_planes_cover_every_pixels_band():
    import torch

    from fixer4d.init import constants as C
    from fixer4d.init.sweep_regions import tile_axis, tile_planes

    centre = torch.tensor([[10, 10, 11], [12, -1, 40]])
    planes = tile_planes(centre, 2, 64).tolist()
    assert planes == list(range(8, 15)) + list(range(38, 43))  # -1 needs none
    assert tile_planes(torch.full((2, 2), -1), 3, 64).numel() == 0
    assert tile_planes(torch.tensor([0, 63]), 3, 64).tolist() == [0, 1, 2, 3, 60, 61, 62, 63]
    many = torch.arange(0, 128, 4).reshape(4, 8)  # noisy centres: the cap keeps the most needed
    assert tile_planes(many, 3, 128).numel() == C.MVS_TILE_MAX_PLANES
    # tiles cover the axis; padded extents stay inside it and hold the margin
    for n in (7, 40, 41, 100):
        tiles = tile_axis(n, 16, 4)
        assert tiles[0][0] == 0 and tiles[-1][1] == n
        assert all(a[1] == b[0] for a, b in zip(tiles, tiles[1:]))
        size = min(n, 24)
        for a, b, p in tiles:
            assert 0 <= p and p + size <= n and p <= a and b <= p + size
            assert (a - p >= 4 or p == 0) and (p + size - b >= 4 or p + size == n)
