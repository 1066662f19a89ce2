"""Capture folders (videos or image folders, any names) with a calibration beside them: layout,
frames, split, synchronization offsets, undistortion."""
from __future__ import annotations

import numpy as np
import pytest

from fixer4d.calib.rig import Rig, RigCamera, distort_points, opencv_K, undistort, undistort_maps
from fixer4d.errors import InputError
from fixer4d.eval.metrics import psnr
from fixer4d.scene import detect_layout, load_scene
from fixer4d.scene.capture import CaptureScene


def _true_rig(scene, ids) -> Rig:
    return Rig([RigCamera(scene.cameras[i].name, scene.cameras[i].width, scene.cameras[i].height, scene.cameras[i].K,
                          scene.cameras[i].w2c) for i in ids], scale="test")


@pytest.mark.parametrize("kind", ["videos", "images"])
def test_capture_opens_with_every_camera_training(tmp_path, tiny4, capture_writer, kind):
    scene, ids = tiny4
    names = capture_writer(scene, tmp_path, ids, kind=kind)
    _true_rig(scene, ids).write(tmp_path / "rig.json")
    assert detect_layout(tmp_path) == "capture"
    cap = load_scene(tmp_path)
    assert isinstance(cap, CaptureScene) and [c.name for c in cap.cameras] == sorted(names)
    assert cap.train_ids == [0, 1, 2, 3] and cap.test_ids == [] and "no held-out camera" in cap.describe()
    assert cap.num_frames == scene.num_frames
    for k, i in enumerate(ids):
        np.testing.assert_allclose(cap.cameras[k].K, scene.cameras[i].K)
        np.testing.assert_allclose(cap.cameras[k].c2w, scene.cameras[i].c2w, atol=1e-9)
        assert psnr(cap.frame(2, k), scene.frame(2, i)) > 40  # lossless video / PNG: only 8-bit rounding
    held = load_scene(tmp_path, holdout=[names[1]])
    assert held.test_ids == [1] and held.train_ids == [0, 2, 3]
    with pytest.raises(InputError, match="no such camera"):
        load_scene(tmp_path, holdout=["nope"])


def test_capture_without_calibration_names_what_to_do(tmp_path, tiny4, capture_writer):
    scene, ids = tiny4
    capture_writer(scene, tmp_path, ids[:2])
    Rig(_true_rig(scene, ids).cameras[:1]).write(tmp_path / "rig.json")
    with pytest.raises(InputError, match="no camera named") as err:
        load_scene(tmp_path)
    assert "images" not in str(err.value) and "rename the videos/folders" in str(err.value)


def test_a_calibrated_camera_without_video_is_refused(tmp_path, tiny4, capture_writer):
    """Three videos beside a four-camera rig.json: refused naming the camera, never run on three silently."""
    scene, ids = tiny4
    capture_writer(scene, tmp_path, ids[:3])
    _true_rig(scene, ids).write(tmp_path / "rig.json")
    orphan = scene.cameras[ids[3]].name
    with pytest.raises(InputError, match=rf"calibrates cameras \['{orphan}'\] that have no video") as err:
        load_scene(tmp_path)
    assert "add their videos, or remove them from the calibration" in str(err.value)


def test_offsets_synchronize_and_mismatches_are_refused(tmp_path, tiny4, capture_writer):
    scene, ids = tiny4
    late = scene.cameras[ids[1]].name
    capture_writer(scene, tmp_path, ids, lead={ids[1]: 2})  # that camera has 2 extra frames first
    _true_rig(scene, ids).write(tmp_path / "rig.json")
    with pytest.raises(InputError, match=rf"not synchronized.*{late} 6.*--offset CAM=N"):
        load_scene(tmp_path)
    cap = load_scene(tmp_path, offsets={late: 2})
    assert cap.num_frames == scene.num_frames
    assert psnr(cap.frame(3, 1), scene.frame(3, ids[1])) > 40
    with pytest.raises(InputError, match="lacks"):
        load_scene(tmp_path, offsets={"cam99": 1})
    # a frame range of the common part works without offsets
    assert load_scene(tmp_path, frame_range=(0, 3)).num_frames == 3


def test_different_frame_rates_are_refused(tmp_path, tiny4, capture_writer):
    scene, ids = tiny4
    capture_writer(scene, tmp_path, ids[:2], fps={ids[1]: 25.0})
    _true_rig(scene, ids).write(tmp_path / "rig.json")
    with pytest.raises(InputError, match=r"different frame rates.*25\.000 fps"):
        load_scene(tmp_path)


def test_offset_syntax():
    from fixer4d.scene.capture import parse_offsets

    assert parse_offsets(["cam02=3", "b=0"]) == {"cam02": 3, "b": 0}
    for bad in ("cam02", "cam02=x", "cam02=-1"):
        with pytest.raises(InputError, match="--offset"):
            parse_offsets([bad])


def test_distorted_render_is_undistorted_back(tiny4):
    """A frame put through a lens model (k1, k2, p1, p2) comes back to the pinhole frame."""
    import cv2

    scene = load_scene("tiny", scale=3.0)  # 192x144: enough pixels for resampling to be a small error
    cam = scene.cameras[tiny4[1][0]]
    rc = RigCamera(cam.name, cam.width, cam.height, cam.K, cam.w2c, {"k1": -0.18, "k2": 0.04, "p1": 0.002, "p2": -0.001})
    # the lens model agrees with OpenCV's projection
    pts = np.random.default_rng(0).uniform([0, 0], [cam.width, cam.height], (50, 2))
    rays = np.c_[(pts - cam.K[:2, 2]) / np.diag(cam.K)[:2], np.ones(50)]
    cv_uv = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), opencv_K(cam.K), rc.coefficients)[0].reshape(-1, 2)
    np.testing.assert_allclose(distort_points(rc, pts), cv_uv + 0.5, atol=1e-9)
    # a distorted image: each distorted pixel shows the pinhole image where the lens sends it from
    # smoothed so that two bilinear resamplings cost little; what remains measures the geometry
    pinhole = cv2.GaussianBlur(scene.frame(1, tiny4[1][0]), (0, 0), 1.5)
    grid = np.stack(np.meshgrid(np.arange(cam.width) + 0.5, np.arange(cam.height) + 0.5), -1).reshape(-1, 2)
    src = cv2.undistortPoints(grid[:, None] - 0.5, opencv_K(cam.K), rc.coefficients, P=opencv_K(cam.K)).reshape(-1, 2)
    src = src.reshape(cam.height, cam.width, 2).astype(np.float32)
    distorted = cv2.remap(pinhole, src[..., 0], src[..., 1], cv2.INTER_LINEAR)
    assert psnr(distorted, pinhole) < 25  # the lens visibly bends the frame
    back = undistort(distorted, undistort_maps(rc))
    inner = (slice(16, -16), slice(16, -16))
    assert psnr(back[inner], pinhole[inner]) > 40
