import numpy as np
import pytest

from fixer4d.errors import InputError
from fixer4d.geometry.camera import Camera
from fixer4d.init.poses import align_cameras, compare_poses, estimate_poses
from fixer4d.init.sparse import sparse_cloud
from planescene import plane_cameras, render_plane
from toyscene import ToyScene


def _rot(axis, deg):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    a = np.radians(deg)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(a) * K + (1 - np.cos(a)) * K @ K


def _moved(cams, s, R, t):
    out = []
    for c in cams:
        c2w = np.eye(4)
        c2w[:3, :3] = R @ c.R
        c2w[:3, 3] = s * R @ c.center + t
        out.append(c.with_pose(c2w))
    return out


def test_compare_poses_is_similarity_invariant():
    cams = ToyScene(32, 24).train_cameras
    est = _moved(cams, 0.3, _rot([1, 2, 3], 70), np.array([5.0, -1.0, 2.0]))
    err = compare_poses(est, cams)
    assert err["rotation_deg_max"] < 1e-4 and err["center_error_rel_max"] < 1e-9
    assert err["scale"] == pytest.approx(1 / 0.3)


def test_compare_poses_reports_a_known_rotation_error():
    cams = ToyScene(32, 24).train_cameras
    bad = cams[0].with_pose(np.block([[cams[0].R @ _rot([0, 1, 0], 2.0), cams[0].center[:, None]], [np.zeros((1, 3)), 1]]))
    err = compare_poses([bad] + cams[1:], cams)
    assert err["per_camera"][0]["rotation_deg"] == pytest.approx(2.0, abs=0.05)
    assert err["center_error_rel_max"] < 1e-9


def test_collinear_rig_alignment_uses_orientations():
    cams = [Camera.look_at([x, 0, 5], [0, 0, 0], width=32, height=24) for x in (-1.0, 0.0, 1.0)]
    est = _moved(cams, 2.0, _rot([0, 0, 1], 30), np.zeros(3))
    sim = align_cameras(est, cams)
    np.testing.assert_allclose(sim.R, _rot([0, 0, 1], -30), atol=1e-9)


@pytest.fixture(scope="module")
def toy():
    return ToyScene(320, 240, num_frames=1)


def test_sfm_recovers_the_rig(toy):
    ims = [toy.frame(0, i) for i in toy.train_ids]
    res = estimate_poses(ims, toy.train_cameras)
    err = compare_poses(res.cameras, toy.train_cameras)
    assert err["rotation_deg_max"] < 1.0 and err["center_error_rel_max"] < 0.02
    assert res.points.shape[0] > 100


def test_sparse_points_lie_on_the_surface(toy):
    ims = [toy.frame(0, i) for i in toy.train_ids]
    cloud, stats = sparse_cloud(ims, toy.train_cameras, 0, 0.0)
    assert len(cloud) > 100 and stats["seconds"] > 0
    cam = toy.train_cameras[0]
    uv, z = cam.project(cloud.points)
    ok = np.all(np.isfinite(uv), 1) & (uv[:, 0] >= 0) & (uv[:, 0] < 320) & (uv[:, 1] >= 0) & (uv[:, 1] < 240)
    gt = toy.depth(0, 0)[uv[ok, 1].astype(int), uv[ok, 0].astype(int)]
    vis = np.isfinite(gt)
    rel = np.abs(z[ok][vis] - gt[vis]) / gt[vis]
    assert np.median(rel) < 0.005


def test_textureless_views_fail_with_advice_on_poses():
    cams = plane_cameras(96, 72)
    flat = [render_plane(c, textured=False)[0] for c in cams]
    with pytest.raises(InputError, match="--poses given"):
        estimate_poses(flat, cams)
    cloud, stats = sparse_cloud(flat, cams, 0, 0.0)
    assert len(cloud) == 0 and stats["inlier_matches"] == 0
