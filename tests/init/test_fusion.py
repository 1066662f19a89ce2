import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fixer4d.errors import InputError
from fixer4d.init.fusion import FusionConfig, consistent_points, fuse_depths
from fixer4d.init.quality import cloud_quality, surface_samples
from planescene import PLANE_Z, plane_cameras, render_plane
from toyscene import ToyScene


def _plane(width=48, height=36):
    cams = plane_cameras(width, height)
    imgs, depths = zip(*(render_plane(c) for c in cams))
    return list(cams), list(imgs), list(depths)


def test_fused_ground_truth_depth_lies_on_the_plane():
    cams, imgs, depths = _plane()
    pts, cols = fuse_depths(imgs, depths, cams)
    assert pts.shape[0] > 1000 and pts.dtype == np.float32
    np.testing.assert_allclose(pts[:, 2], PLANE_Z, atol=1e-4)
    assert np.all((cols >= 0) & (cols <= 1))


def test_fused_ground_truth_depth_lands_on_the_true_surface():
    scene = ToyScene(64, 48, num_frames=1)
    ids = scene.train_ids
    depths = [scene.depth(0, i) for i in ids]
    cams = [scene.cameras[i] for i in ids]
    pts, _ = fuse_depths([scene.frame(0, i) for i in ids], depths, cams)
    surface, scale = surface_samples(depths, cams)
    q = cloud_quality(pts, surface, scale)
    assert pts.shape[0] > 500
    # points are voxel centroids of exact surface points: far below the 1% completeness tolerance
    assert q["accuracy"] < 0.002 * scale
    assert q["completeness"] > 0.8


def test_disagreeing_view_is_rejected():
    cams, imgs, depths = _plane()
    depths[0] = depths[0] * 1.2  # view 0 is wrong: nobody agrees with it
    raw, _ = consistent_points(imgs, depths, cams, min_views=1)
    assert np.abs(raw[:, 2] - PLANE_Z).max() < 1e-6


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.sampled_from([0.0, np.nan, np.inf, -np.inf, -1.0, 1.0]), min_size=4, max_size=4),
       st.integers(0, 2**31 - 1))
def test_bad_depth_values_never_produce_nan(kinds, seed):
    cams, imgs, depths = _plane(24, 18)
    rng = np.random.default_rng(seed)
    for i, kind in enumerate(kinds):
        bad = rng.random(depths[i].shape) < 0.5
        if kind != 1.0:
            depths[i] = np.where(bad, np.float32(kind), depths[i])
    pts, cols = fuse_depths(imgs, depths, cams, config=FusionConfig(outlier_neighbors=0))
    assert np.all(np.isfinite(pts)) and np.all(np.isfinite(cols))
    if pts.shape[0]:
        np.testing.assert_allclose(pts[:, 2], PLANE_Z, atol=1e-4)


def test_empty_masks_give_an_empty_cloud():
    cams, imgs, depths = _plane(24, 18)
    masks = [np.zeros_like(d, bool) for d in depths]
    pts, cols = fuse_depths(imgs, depths, cams, masks)
    assert pts.shape == (0, 3) and cols.shape == (0, 3)
    pts, _ = fuse_depths(imgs, [np.zeros_like(d) for d in depths], cams)
    assert pts.shape == (0, 3)


def test_single_view_and_mismatched_sizes_raise():
    cams, imgs, depths = _plane(24, 18)
    with pytest.raises(InputError, match="other agreeing views"):
        fuse_depths(imgs[:1], depths[:1], cams[:1])
    # k = 0 accepts a single view
    pts, _ = fuse_depths(imgs[:1], depths[:1], cams[:1], config=FusionConfig(min_views=0))
    assert pts.shape[0] > 0
    with pytest.raises(InputError, match="depth map 1"):
        fuse_depths(imgs, [depths[0], depths[1][:10]] + depths[2:], cams)
    with pytest.raises(InputError, match="image 2"):
        fuse_depths(imgs[:2] + [imgs[2][:, :10]] + imgs[3:], depths, cams)
    with pytest.raises(InputError, match="one of each"):
        fuse_depths(imgs, depths[:3], cams)


def test_voxel_down_sample_averages_each_voxel():
    from fixer4d.init.fusion import voxel_down_sample

    pts = np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [5.0, 5.0, 5.0], [0.2, 0.2, 0.2]])
    cols = np.array([[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0], [1.0, 1.0, 1.0]])
    p, c = voxel_down_sample(pts, cols, 1.0)
    # the grid starts half a voxel below the minimum: the first, second and last points share
    # a voxel; voxels in lexicographic order of their index
    assert np.allclose(p, [[0.1, 0.2 / 3, 0.2 / 3], [5.0, 5.0, 5.0]])
    assert np.allclose(c, [[2 / 3, 2 / 3, 1 / 3], [0, 0, 1.0]])


def test_statistical_inliers_drop_an_isolated_point():
    from fixer4d.init.fusion import statistical_inliers

    rng = np.random.default_rng(0)
    pts = np.concatenate([rng.normal(0, 0.1, (300, 3)), [[5.0, 5.0, 5.0]]])
    keep = statistical_inliers(pts, 20, 2.0)
    assert not keep[-1] and keep[:-1].mean() > 0.9
    # a duplicated point has mean neighbour distance 0 with k = 1: open3d drops it, so do we
    assert not statistical_inliers(np.array([[0.0, 0, 0], [0.0, 0, 0], [1.0, 0, 0]]), 1, 2.0).any()
