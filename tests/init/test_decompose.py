"""Decomposed initialization (fixer4d.init.decompose): geometry helpers and end-to-end decisions."""
from __future__ import annotations

import json

import numpy as np
import pytest

from fixer4d.geometry.camera import Camera
from fixer4d.init import InitConfig, run_init
from fixer4d.init import decompose as D
from fixer4d.init import tracks as T


def _rig(n: int = 3) -> list[Camera]:
    return [Camera.look_at(np.array([x, 0.0, 5.0]), np.zeros(3), fov_y=np.radians(50.0), width=80, height=60)
            for x in np.linspace(-1.0, 1.0, n)]


def test_triangulate_recovers_points_and_rejects_single_views():
    rng = np.random.default_rng(0)
    X = rng.uniform(-0.5, 0.5, (50, 3))
    cams = _rig()
    uvs = np.stack([c.project(X)[0] for c in cams])
    ok = np.ones((3, 50), bool)
    ok[1:, :5] = False  # only one view for the first 5 points
    Y, good = T.triangulate(uvs, ok, cams)
    assert not good[:5].any() and good[5:].all()
    assert np.allclose(Y[5:], X[5:], atol=1e-6)


def test_fit_tracks_picks_the_smallest_sufficient_degree():
    cams = _rig()
    dts = np.array([-0.1, -0.05, 0.0, 0.05, 0.1, 0.15])
    x0 = np.array([[0.0, 0.0, 0.0], [0.2, 0.1, 0.0], [-0.2, 0.0, 0.3]])
    vel = np.array([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [1.0, 1.0, 0.0]])
    acc = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, -30.0, 0.0]])
    X = x0[None] + dts[:, None, None] * vel[None] + dts[:, None, None] ** 2 * acc[None]
    obs = np.stack([np.stack([c.project(X[s])[0] for c in cams]) for s in range(len(dts))])
    coeffs, degree, rms = T.fit_tracks(dts, X, np.ones((len(dts), 3), bool), obs, np.ones(obs.shape[:3], bool), cams)
    assert degree.tolist() == [0, 1, 2]
    assert np.all(rms < 1e-3)
    assert np.allclose(coeffs[1, 1], vel[1], atol=1e-6) and np.allclose(coeffs[2, 2], acc[2], atol=1e-4)


def test_static_median_ignores_moving_pixels():
    imgs = np.zeros((5, 4, 4, 3), np.float32)
    imgs[:, 0, 0] = 0.2
    moving = np.zeros((5, 4, 4), bool)
    imgs[0:3, 1, 1] = 0.9  # an object over the pixel in 3 of 5 frames: the plain median is wrong
    moving[0:3, 1, 1] = True
    imgs[:, 2, 2] = 0.7
    moving[:, 2, 2] = True  # moves in every frame: falls back to the plain median
    med = D.static_median(imgs, moving)
    assert np.allclose(med[0, 0], 0.2) and np.allclose(med[1, 1], 0.0) and np.allclose(med[2, 2], 0.7)


def test_crop_camera_and_roi_boxes():
    from fixer4d.init.sweep_regions import crop_camera, roi_boxes

    cam = _rig(1)[0]
    crop = crop_camera(cam, (10, 5, 50, 45))
    X = np.array([[0.1, 0.1, 0.0]])
    assert np.allclose(crop.project(X)[0], cam.project(X)[0] - [10, 5])
    mask = np.zeros((60, 80), bool)
    mask[20:30, 40:45] = True
    assert roi_boxes(mask, 3) == [(37, 17, 48, 33)]
    assert roi_boxes(np.zeros((60, 80), bool), 3) == []
    # two regions far apart stay two boxes (less to sweep than their union); near ones merge
    mask[2:6, 2:6] = True
    assert roi_boxes(mask, 1) == [(1, 1, 7, 7), (39, 19, 46, 31)]
    mask[20:30, 46:50] = True  # overlaps the first region's box once widened
    assert roi_boxes(mask, 1) == [(1, 1, 7, 7), (39, 19, 51, 31)]


def test_local_angular_velocity_of_a_spinning_blob():
    rng = np.random.default_rng(1)
    pts = rng.normal(0, 0.2, (200, 3))
    w = np.array([0.0, 3.0, 0.0])
    spin = np.cross(w, pts)
    omega, gain = T.local_angular_velocity(pts, spin, np.ones(200, bool), np.zeros(200, int))
    assert np.allclose(np.median(omega, 0), w, atol=0.05) and np.median(gain) > 0.95
    omega, gain = T.local_angular_velocity(pts, np.tile([1.0, 0, 0], (200, 1)), np.ones(200, bool), np.zeros(200, int))
    assert np.abs(omega).max() < 1e-6 and gain.max() <= 1e-6


def _config() -> InitConfig:
    cfg = InitConfig()
    cfg.mvs.planes = 48
    return cfg


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory):
    from fixer4d.scene import load_scene

    out = tmp_path_factory.mktemp("tiny_dec")
    scene = load_scene("tiny")
    clouds, report = run_init(scene, "mvs", out, frames=[0, 1, 2, 3], config=_config(), progress=False)
    return scene, out, clouds, report


def test_decomposed_init_writes_its_files_and_report(tiny_run):
    from fixer4d.init.masks import load_masks

    scene, out, clouds, report = tiny_run
    dec = D.DecomposedInit.load(out)
    on_disk = json.loads((out / "init_report.json").read_text())
    assert on_disk["decomposition"]["static_points"] == dec.num_static > 0
    assert on_disk["decomposition"]["moving_points"] == dec.num_dynamic > 0
    assert on_disk["seconds"]["preparation"] > 0 and on_disk["points_per_frame"] == [len(c) for c in clouds]
    masks, ids, frames = load_masks(out / "masks.npz")
    assert masks.shape[:2] == (len(scene.train_ids), 4) and frames == [0, 1, 2, 3]
    # every frame's cloud = the one static cloud + that frame's moving points
    for c in clouds:
        assert len(c) == dec.num_static + int((dec.dyn_frames == c.frame).sum())
    assert set(np.unique(dec.dyn_frames)) <= {0, 1, 2, 3}
    assert dec.dyn_coeffs.shape == (dec.num_dynamic, 3, 3) and np.all(np.isfinite(dec.dyn_coeffs))


def test_moving_object_scene_picks_dynamic_terms(tiny_run):
    from fixer4d.model.terms import decide_terms

    _, out, _, _ = tiny_run
    dec = decide_terms(D.DecomposedInit.load(out))
    assert dec.model_config.temporal_opacity and dec.model_config.motion_degree >= 1
    assert int(dec.dynamic_keep.sum()) >= 50


def test_static_scene_picks_no_dynamic_terms(tmp_path):
    from fixer4d.model.terms import decide_terms
    from fixer4d.scene import load_scene

    scene = load_scene("static_matte", scale=0.4)
    run_init(scene, "mvs", tmp_path, frames=[0, 5, 9], config=_config(), progress=False)
    dec = decide_terms(D.DecomposedInit.load(tmp_path))
    cfg = dec.model_config
    assert not cfg.has_time_terms and cfg.sh_degree == 0
    assert int(dec.dynamic_keep.sum()) == 0


@pytest.fixture(scope="module")
def spec_decisions(tmp_path_factory):
    """Model terms decided on the two specs that call for different terms (4 init frames, 64 planes)."""
    from fixer4d.model.terms import decide_terms
    from fixer4d.scene import load_scene

    out = {}
    for name in ("slow_rigid", "fast_thin"):
        scene = load_scene(name)
        cfg = InitConfig()
        cfg.mvs.planes = 64
        folder = tmp_path_factory.mktemp(name)
        run_init(scene, "mvs", folder, frames=list(range(0, scene.num_frames, 3)), config=cfg, progress=False)
        out[name] = decide_terms(D.DecomposedInit.load(folder))
    return out


def test_specs_pick_different_terms(spec_decisions):
    slow, fast = spec_decisions["slow_rigid"].model_config, spec_decisions["fast_thin"].model_config
    # measured: slow_rigid (1, no rotation, temporal, SH 0); fast_thin (1, rotation, temporal, SH 0)
    assert slow.temporal_opacity and fast.temporal_opacity
    assert slow.motion_degree >= 1 and fast.motion_degree >= 1
    assert not slow.rotation_velocity and slow.sh_degree == 0  # slow, matte, barely turning
    assert fast.rotation_velocity  # blades spinning at 540 deg/s
    assert slow != fast
