"""The Dynamic3DGaussians/Panoptic layout: the real basketball subset and a generated folder."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from fixer4d.errors import InputError
from fixer4d.scene import load_scene
from fixer4d.scene.panoptic import PanopticScene


def test_panoptic_basketball(panoptic_dir):
    scene = load_scene(panoptic_dir)
    assert isinstance(scene, PanopticScene)
    assert [scene.cameras[i].name for i in scene.train_ids] == ["1", "9", "18", "23"]
    assert [scene.cameras[i].name for i in scene.test_ids] == ["30"]
    assert scene.num_frames == 150 and scene.fps == 30.0
    rgb = scene.frame(0, scene.test_ids[0])
    assert rgb.shape == (360, 640, 3) and rgb.dtype == np.float32 and 0 <= rgb.min() and rgb.max() <= 1
    assert rgb.std() > 0.05
    mask = scene.mask(0, scene.train_ids[0])
    assert mask.dtype == bool and mask.shape == (360, 640) and 0.01 < mask.mean() < 0.5
    assert scene.mask(0, scene.test_ids[0]) is None  # seg/ holds the train cameras only
    # w2c was inverted correctly: the cameras ring one region that every camera sees in front of it.
    centers = np.stack([c.center for c in scene.cameras])
    dirs = np.stack([c.forward for c in scene.cameras])
    A = sum(np.eye(3) - np.outer(d, d) for d in dirs)
    b = sum((np.eye(3) - np.outer(d, d)) @ c for c, d in zip(centers, dirs))
    focus = np.linalg.solve(A, b)  # the point closest to every optical axis
    for cam in scene.cameras:
        uv, z = cam.project(focus[None])
        assert z[0] > 0 and 0 <= uv[0, 0] < cam.width and 0 <= uv[0, 1] < cam.height


def test_panoptic_scale_and_frame_range(panoptic_dir):
    scene = load_scene(panoptic_dir, scale=0.25, frame_range=(100, 110), test_ids=[30, 9], train_ids=[1, 18, 23])
    assert scene.num_frames == 10
    assert [c.name for c in scene.cameras] == ["1", "18", "23", "30", "9"]
    assert scene.frame(9, 0).shape == (90, 160, 3)
    assert scene.cameras[0].width == 160


def make_panoptic(root: Path, cams=(3, 5, 8), test_cams=(4,), frames=3) -> Path:
    """A small Dynamic3DGaussians-layout folder with generated JPEGs."""
    import cv2

    w, h = 32, 24
    for split, ids in (("train", cams), ("test", test_cams)):
        meta = {"w": w, "h": h, "k": [], "w2c": [], "fn": [], "cam_id": []}
        for f in range(frames):
            meta["k"].append([[[30.0, 0, 16], [0, 30.0, 12], [0, 0, 1]] for _ in ids])
            meta["w2c"].append([np.eye(4).tolist() for _ in ids])
            meta["fn"].append([f"{c}/{f:06d}.jpg" for c in ids])
            meta["cam_id"].append(list(ids))
        (root / f"{split}_meta.json").write_text(json.dumps(meta))
        for c in ids:
            (root / "ims" / str(c)).mkdir(parents=True, exist_ok=True)
            for f in range(frames):
                cv2.imwrite(str(root / "ims" / str(c) / f"{f:06d}.jpg"), np.full((h, w, 3), 40 * f + c, np.uint8))
    return root


def test_generated_panoptic_folder(tmp_path):
    scene = load_scene(make_panoptic(tmp_path))
    assert [c.name for c in scene.cameras] == ["3", "5", "8", "4"]
    assert scene.train_ids == [0, 1, 2] and scene.test_ids == [3]
    assert scene.frame(2, 1).mean() == pytest.approx((80 + 5) / 255, abs=2 / 255)
    assert scene.mask(0, 0) is None


def test_panoptic_missing_image(tmp_path):
    root = make_panoptic(tmp_path)
    (root / "ims" / "5" / "000002.jpg").unlink()
    with pytest.raises(InputError, match=r"ims/5/000002.jpg: image missing"):
        load_scene(root)
    scene = load_scene(root, frame_range=(0, 2))  # the fix the message names
    assert scene.num_frames == 2


def test_panoptic_bad_metadata(tmp_path):
    root = make_panoptic(tmp_path)
    meta = json.loads((root / "train_meta.json").read_text())
    meta["w2c"][0][1][2][3] = float("nan")
    (root / "train_meta.json").write_text(json.dumps(meta))
    with pytest.raises(InputError, match="train_meta.json: camera 5 .*non-finite"):
        load_scene(root)
    (root / "train_meta.json").write_text("{}")
    with pytest.raises(InputError, match=r"train_meta.json: missing keys"):
        load_scene(root)


def test_panoptic_unknown_camera_id(tmp_path):
    with pytest.raises(InputError, match=r"camera ids \[99\]"):
        load_scene(make_panoptic(tmp_path), train_ids=[3, 99])


def test_panoptic_bounds_from_the_train_cameras(panoptic_dir):
    """Panoptic stores no bounds: they come from the train cameras' common view, around the point
    the dome cameras look at, independent of the image scale and of the held-out cameras."""
    from fixer4d.geometry.rig import rig_focus

    scene = load_scene(panoptic_dir, scale=0.5)
    b = scene.bounds()
    focus = rig_focus(scene.train_cameras)
    assert 0 < b.near < b.far
    assert np.all(b.bbox_min < focus) and np.all(focus < b.bbox_max)
    for cam in scene.train_cameras:
        z = cam.world_to_camera(focus[None])[0, 2]
        assert b.near < z < b.far
    full = load_scene(panoptic_dir, test_ids=[])
    np.testing.assert_allclose(full.bounds().bbox_min, b.bbox_min, rtol=1e-6, atol=1e-9)
    # Its seg/ masks are foreground (people), used by the moving-content masks.
    assert scene.mask(0, scene.train_ids[0]) is not None
