"""Neural3DV layout: LLFF conversion, make-scene round trip, video I/O and every bad input."""
from __future__ import annotations

import json

import numpy as np
import pytest

from fixer4d.errors import InputError
from fixer4d.geometry.camera import Camera
from fixer4d.scene import load_scene
from fixer4d.geometry.llff import cameras_to_llff, llff_to_cameras, read_poses_bounds
from fixer4d.scene.n3dv import Neural3DVScene
from fixer4d.scene.synthetic import SyntheticScene, look_at_c2w
from fixer4d.scene.video import VideoReader, probe_video, write_video

# Lossy H.264 (crf 12, 4:4:4) against the exact frames: mean error well under one percent.
CODEC_MEAN_TOL = 0.02
CODEC_P99_TOL = 0.15


def random_cameras(n: int, rng: np.random.Generator) -> list[Camera]:
    cams = []
    for i in range(n):
        eye = rng.uniform(-3, 3, 3)
        c2w = look_at_c2w(eye, eye + rng.normal(size=3), rng.normal(size=3))
        w, h = int(rng.integers(16, 2000)), int(rng.integers(16, 2000))
        f = rng.uniform(50, 3000)
        cams.append(Camera(np.array([[f, 0, w / 2], [0, f, h / 2], [0, 0, 1]]), c2w, w, h, f"cam{i:02d}"))
    return cams


def assert_same_cameras(a: list[Camera], b: list[Camera], tol: float = 1e-9) -> None:
    assert len(a) == len(b)
    for ca, cb in zip(a, b):
        assert (ca.width, ca.height, ca.name) == (cb.width, cb.height, cb.name)
        np.testing.assert_allclose(ca.K, cb.K, rtol=0, atol=tol * max(1.0, np.abs(cb.K).max()))
        np.testing.assert_allclose(ca.c2w, cb.c2w, rtol=0, atol=tol)


def test_llff_round_trip_through_a_file(tmp_path):
    cams = random_cameras(7, np.random.default_rng(0))
    near_far = np.stack([np.linspace(0.5, 1, 7), np.linspace(10, 20, 7)], 1)
    np.save(tmp_path / "poses_bounds.npy", cameras_to_llff(cams, near_far))
    back, nf = llff_to_cameras(read_poses_bounds(tmp_path / "poses_bounds.npy"), [c.name for c in cams])
    assert_same_cameras(back, cams)
    np.testing.assert_array_equal(nf, near_far)


def test_llff_axes_are_pinned():
    """LLFF's [down, right, back] columns -> OpenCV [right, down, forward]."""
    row = np.zeros(17)
    m = np.zeros((3, 5))
    m[:, 0] = [0, -1, 0]  # down = world -y
    m[:, 1] = [1, 0, 0]   # right = world +x
    m[:, 2] = [0, 0, 1]   # back = world +z (so the camera looks along -z)
    m[:, 3] = [1, 2, 3]
    m[:, 4] = [480, 640, 500]
    row[:15] = m.reshape(-1)
    row[15:] = [1, 100]
    (cam,), _ = llff_to_cameras(row[None])
    np.testing.assert_array_equal(cam.c2w[:3, :3], [[1, 0, 0], [0, -1, 0], [0, 0, -1]])
    np.testing.assert_array_equal(cam.center, [1, 2, 3])
    np.testing.assert_array_equal(cam.K, [[500, 0, 320], [0, 500, 240], [0, 0, 1]])
    assert (cam.width, cam.height) == (640, 480)


def test_llff_rejects_cameras_it_cannot_store():
    cam = random_cameras(1, np.random.default_rng(1))[0]
    K = cam.K.copy()
    K[0, 2] += 3
    with pytest.raises(InputError, match="centred principal point"):
        cameras_to_llff([Camera(K, cam.c2w, cam.width, cam.height, "off")], np.array([1.0, 2.0]))


def test_make_scene_round_trip(tiny_n3dv, tiny_scene):
    scene = load_scene(tiny_n3dv)
    assert isinstance(scene, Neural3DVScene)
    assert (scene.num_frames, scene.fps) == (tiny_scene.num_frames, tiny_scene.fps)
    assert scene.train_ids == tiny_scene.train_ids and scene.test_ids == tiny_scene.test_ids
    assert_same_cameras(scene.cameras, tiny_scene.cameras)
    assert scene.has_depth
    for f in range(scene.num_frames):
        for c in range(len(scene.cameras)):
            err = np.abs(scene.frame(f, c) - tiny_scene.frame(f, c))
            assert err.mean() < CODEC_MEAN_TOL and np.quantile(err, 0.99) < CODEC_P99_TOL
            np.testing.assert_array_equal(scene.depth(f, c), tiny_scene.depth(f, c))
    b, gt = scene.bounds(), tiny_scene.bounds()
    assert (b.near, b.far) == pytest.approx((gt.near, gt.far))
    np.testing.assert_allclose(b.bbox_min, gt.bbox_min)
    meta = json.loads((tiny_n3dv / "scene.json").read_text())
    assert meta["spec"]["name"] == "tiny" and meta["train_ids"] == tiny_scene.train_ids


def test_n3dv_frame_range_scale_and_camera_ids(tiny_n3dv, tiny_scene):
    scene = load_scene(tiny_n3dv, scale=0.5, frame_range=(1, 3), train_ids=[0, 7, 2, 5], test_ids=[3])
    assert [c.name for c in scene.cameras] == ["cam00", "cam02", "cam03", "cam05", "cam07"]
    assert [scene.cameras[i].name for i in scene.train_ids] == ["cam00", "cam07", "cam02", "cam05"]
    assert [scene.cameras[i].name for i in scene.test_ids] == ["cam03"]
    assert scene.num_frames == 2 and scene.frame(0, 1).shape == (24, 32, 3)
    np.testing.assert_allclose(scene.cameras[1].K[:2], tiny_scene.cameras[2].K[:2] * 0.5)
    full = load_scene(tiny_n3dv)
    small = full.frame(2, 2)[::2, ::2]
    assert np.abs(scene.frame(1, 1) - small).mean() < 0.1  # same content, half size
    assert scene.depth(1, 1).shape == (24, 32)


def test_default_split_of_a_21_camera_rig(tmp_path):
    """Without scene.json a full Neural3DV rig trains on cam01, 10, 13, 20 and holds out the rest."""
    cams = [Camera(Camera.intrinsics_from_fov(0.8, 16, 16),
                   look_at_c2w(np.array([0.1 * i, 0.0, 3.0]), np.array([0.1 * i, 0.0, 0.0]), np.array([0.0, 1.0, 0.0])),
                   16, 16, f"cam{i:02d}") for i in range(21)]
    np.save(tmp_path / "poses_bounds.npy", cameras_to_llff(cams, np.array([1.0, 5.0])))
    frames = [np.full((16, 16, 3), 0.5, np.float32)] * 2
    for i in range(21):
        write_video(tmp_path / f"cam{i:02d}.mp4", frames, 30)
    scene = load_scene(tmp_path)
    assert scene.train_ids == [1, 10, 13, 20]
    assert scene.test_ids[0] == 0 and sorted(scene.test_ids + scene.train_ids) == list(range(21))
    assert scene.num_frames == 2 and not scene.has_depth and scene.depth(0, 0) is None


def test_video_reader_random_access_and_bounded_cache(tmp_path):
    rng = np.random.default_rng(0)
    frames = [np.clip(rng.random((32, 48, 3)) * 0.2 + i / 40, 0, 1).astype(np.float32) for i in range(30)]
    write_video(tmp_path / "v.mp4", frames, 24)
    info = probe_video(tmp_path / "v.mp4")
    assert (info.width, info.height, info.num_frames, info.fps) == (48, 32, 30, 24.0)
    reader = VideoReader(tmp_path / "v.mp4", cache_frames=3)
    for i in (0, 1, 29, 5, 4, 17, 0, 28):
        img = reader.frame(i).astype(np.float32) / 255
        assert np.abs(img.mean() - frames[i].mean()) < 0.01  # the right frame (means differ by 0.025)
        assert len(reader._cache) <= 3


# ---------------------------------------------------------------------------- bad input
def test_missing_poses_bounds_makes_a_capture_to_calibrate(n3dv_copy, monkeypatch, tmp_path):
    """Videos without poses_bounds.npy are a capture (fixer4d.scene.capture): its rig is
    self-calibrated, and a rig the frames cannot fix is refused naming the files that would."""
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    (n3dv_copy / "poses_bounds.npy").unlink()
    with pytest.raises(InputError, match="self-calibration refused") as info:
        load_scene(n3dv_copy)
    assert "poses_bounds.npy" in str(info.value)


def test_missing_videos(n3dv_copy):
    for p in n3dv_copy.glob("cam*.mp4"):
        p.unlink()
    with pytest.raises(InputError, match="no camXX.mp4"):
        load_scene(n3dv_copy)


def test_requested_camera_without_video(n3dv_copy):
    (n3dv_copy / "cam03.mp4").unlink()
    with pytest.raises(InputError, match="cam03.mp4"):
        load_scene(n3dv_copy, train_ids=[0, 2, 3, 5])


def test_corrupt_mp4(n3dv_copy):
    (n3dv_copy / "cam01.mp4").write_bytes(b"this is not a video" * 100)
    with pytest.raises(InputError, match="cam01.mp4.*corrupt or truncated"):
        load_scene(n3dv_copy)


def test_truncated_mp4(n3dv_copy):
    p = n3dv_copy / "cam04.mp4"
    data = p.read_bytes()
    p.write_bytes(data[: len(data) // 2])
    with pytest.raises(InputError, match="cam04.mp4.*corrupt or truncated"):
        scene = load_scene(n3dv_copy)
        for f in range(scene.num_frames):
            scene.frame(f, 4)


def test_cameras_with_different_frame_counts(n3dv_copy, tiny_scene):
    write_video(n3dv_copy / "cam02.mp4", [tiny_scene.frame(f, 2) for f in range(3)], 30)
    with pytest.raises(InputError, match=r"cam02.mp4.*frame_range") as info:
        load_scene(n3dv_copy)
    assert "3 frames" in str(info.value)
    assert load_scene(n3dv_copy, frame_range=(0, 3)).num_frames == 3  # the fix the message names


def test_camera_absent_from_poses_bounds(n3dv_copy):
    pb = np.load(n3dv_copy / "poses_bounds.npy")
    np.save(n3dv_copy / "poses_bounds.npy", pb[:7])
    meta = json.loads((n3dv_copy / "scene.json").read_text())
    meta.pop("pose_cameras")
    (n3dv_copy / "scene.json").write_text(json.dumps(meta))
    with pytest.raises(InputError, match=r"poses_bounds.npy: 7 pose rows for 8 camera videos.*cam07.mp4"):
        load_scene(n3dv_copy)
    # With an explicit row -> camera table, the message names the camera missing from it.
    meta["pose_cameras"] = [0, 1, 2, 3, 4, 5, 6]
    (n3dv_copy / "scene.json").write_text(json.dumps(meta))
    with pytest.raises(InputError, match=r"cam07.mp4: camera id 7 is absent from .*poses_bounds.npy"):
        load_scene(n3dv_copy)


def test_nan_in_poses(n3dv_copy):
    pb = np.load(n3dv_copy / "poses_bounds.npy")
    pb[2, 3] = np.nan
    np.save(n3dv_copy / "poses_bounds.npy", pb)
    with pytest.raises(InputError, match=r"poses_bounds.npy: non-finite .* rows \[2\]"):
        load_scene(n3dv_copy)


def test_poses_bounds_of_the_wrong_shape(n3dv_copy):
    np.save(n3dv_copy / "poses_bounds.npy", np.zeros((8, 15)))
    with pytest.raises(InputError, match=r"poses_bounds.npy: expected an \(N, 17\) array"):
        load_scene(n3dv_copy)


def test_missing_ground_truth_depth(n3dv_copy):
    (n3dv_copy / "depth" / "cam01.npz").unlink()
    scene = load_scene(n3dv_copy)
    with pytest.raises(InputError, match="cam01.npz"):
        scene.depth(0, 1)


def test_export_replaces_atomically(tiny_n3dv, tmp_path):
    """A second make-scene into the same folder swaps the whole folder (no stale files)."""
    from fixer4d.scene.export import export_n3dv

    out = tmp_path / "scene"
    export_n3dv(SyntheticScene("tiny"), out, progress=False)
    (out / "stale.txt").write_text("old")
    export_n3dv(SyntheticScene("tiny", frame_range=(0, 2)), out, progress=False)
    assert not (out / "stale.txt").exists()
    assert load_scene(out).num_frames == 2
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temporaries left
