"""Synthetic scenes: specs, rig, lazy frames, effect sets, load_scene."""
from __future__ import annotations

import copy
import json

import numpy as np
import pytest

from fixer4d.errors import InputError
from fixer4d.scene import MultiViewVideo, SyntheticScene, load_scene, motion, raycast
from fixer4d.geometry.rig import centre_camera
from fixer4d.scene.synthetic import builtin_spec_path


def test_demo_rig_and_split():
    scene = load_scene("demo")
    assert isinstance(scene, SyntheticScene) and isinstance(scene, MultiViewVideo)
    assert len(scene.cameras) == 16 and [c.name for c in scene.cameras] == [f"cam{i:02d}" for i in range(16)]
    assert (scene.cameras[0].width, scene.cameras[0].height) == (200, 150)
    assert scene.num_frames == 20 and scene.fps == 30
    assert scene.train_ids == [0, 3, 12, 15]  # the corners of the 4x4 grid
    assert scene.center_id in scene.test_ids and sorted(scene.train_ids + scene.test_ids) == list(range(16))
    assert scene.effects == {"motion", "specular"}
    assert scene.has_depth


def test_tiny_split_is_most_separated(tiny_scene):
    assert len(tiny_scene.cameras) == 8 and tiny_scene.num_frames == 4
    assert tiny_scene.train_ids[0] == 0 and tiny_scene.train_ids[-1] == 7  # arc ends
    assert centre_camera(tiny_scene.cameras) not in tiny_scene.train_ids
    assert set(tiny_scene.test_ids) == set(range(8)) - set(tiny_scene.train_ids)


def test_world_up_is_up_in_the_image():
    """A point above the rig target projects above it in every camera (OpenCV image y down)."""
    scene = load_scene("demo")
    target = np.array(scene.spec["rig"]["target"])
    for cam in scene.cameras:
        uv, z = cam.project(np.stack([target, target + [0, 1.0, 0], target + [1.0, 0, 0]]))
        assert np.all(z > 0)
        assert uv[1, 1] < uv[0, 1]  # up -> smaller v
        assert uv[2, 0] > uv[0, 0]  # world +x -> right


def test_frames_are_lazy_cached_and_valid(tiny_scene):
    rgb = tiny_scene.frame(1, 2)
    assert rgb.shape == (48, 64, 3) and rgb.dtype == np.float32 and 0 <= rgb.min() and rgb.max() <= 1
    assert tiny_scene.frame(1, 2) is rgb  # the LRU of base.py
    depth = tiny_scene.depth(1, 2)
    assert depth.shape == (48, 64) and depth.dtype == np.float32
    assert np.all(np.isfinite(depth))  # walled room: every ray hits something
    gt_rgb, gt_depth = tiny_scene.render_gt(tiny_scene.cameras[2], tiny_scene.time(1))
    np.testing.assert_array_equal(gt_rgb, rgb)
    np.testing.assert_array_equal(gt_depth, depth)
    # The ball moves between frames, the wall does not.
    assert np.abs(tiny_scene.frame(0, 2) - tiny_scene.frame(3, 2)).max() > 0.2


def test_depth_only_path_equals_full_render(tiny_scene):
    fresh = SyntheticScene("tiny")
    np.testing.assert_array_equal(fresh.depth(2, 5), tiny_scene.render_gt(tiny_scene.cameras[5], tiny_scene.time(2))[1])


def test_frame_range_and_scale():
    full = SyntheticScene("tiny")
    part = SyntheticScene("tiny", frame_range=(1, 3))
    assert part.num_frames == 2 and part.time(1) == 0.5
    np.testing.assert_array_equal(part.frame(1, 4), full.frame(2, 4))
    half = load_scene("tiny", scale=0.5)
    assert half.frame(0, 0).shape == (24, 32, 3)
    np.testing.assert_allclose(half.cameras[0].K[:2], full.cameras[0].K[:2] * 0.5)
    with pytest.raises(InputError, match="frame_range"):
        SyntheticScene("tiny", frame_range=(2, 9))


def test_bounds_come_from_the_train_cameras_not_ground_truth(tiny_scene, monkeypatch):
    """bounds() is the train cameras' common view: no ray is cast, held-out cameras play no part."""
    from fixer4d.scene.synthetic import SyntheticScene

    scene = SyntheticScene("tiny")
    monkeypatch.setattr(raycast, "render", lambda *a, **k: (_ for _ in ()).throw(AssertionError("ray-cast")))
    b = scene.bounds()
    moved = SyntheticScene("tiny", test_ids=[scene.test_ids[0]])
    moved.cameras[scene.test_ids[0]] = moved.cameras[scene.test_ids[0]].with_pose(np.eye(4))
    b2 = moved.bounds()
    assert (b.near, b.far) == (b2.near, b2.far)
    np.testing.assert_array_equal(b.bbox_min, b2.bbox_min)
    monkeypatch.undo()
    # The true surface points every train camera sees lie inside it.
    cams = scene.train_cameras
    pts = np.concatenate([c.backproject_depth(np.where(np.isfinite(d), d, 0.0))[np.isfinite(d)]
                          for c, d in ((scene.cameras[i], scene.depth(0, i)) for i in scene.train_ids)])
    seen = np.ones(len(pts), bool)
    for c in cams:
        uv, z = c.project(pts)
        with np.errstate(invalid="ignore"):
            seen &= (z > 0) & (uv[:, 0] >= 0) & (uv[:, 0] <= c.width) & (uv[:, 1] >= 0) & (uv[:, 1] <= c.height)
    assert seen.sum() > 100
    tol = 0.02 * (b.bbox_max - b.bbox_min)
    assert np.all(pts[seen] >= b.bbox_min - tol) and np.all(pts[seen] <= b.bbox_max + tol)


def test_true_bounds_contain_the_content(tiny_scene):
    b = tiny_scene.true_bounds()
    assert 0 < b.near < b.far
    for f in range(tiny_scene.num_frames):
        d = tiny_scene.depth(f, 0)
        assert b.near <= d.min() and d.max() <= b.far
    ball = tiny_scene.world.objects[-1]
    for f in range(tiny_scene.num_frames):
        c, _ = motion.apply_motion(ball.center, ball.rotation, ball.motions, tiny_scene.seconds(tiny_scene.time(f)))
        assert np.all(b.bbox_min <= c) and np.all(c <= b.bbox_max)


def test_static_matte_spec_never_evaluates_motion_or_specular(monkeypatch):
    def forbidden(*args, **kwargs):
        raise AssertionError("an effect the spec does not ask for was evaluated")

    scene = load_scene("static_matte", scale=0.25)
    assert scene.effects == frozenset()
    monkeypatch.setattr(raycast, "apply_motion", forbidden)
    monkeypatch.setattr(raycast, "specular_term", forbidden)
    monkeypatch.setattr(raycast, "changed_light", forbidden)
    scene.render_gt(scene.cameras[0], 0.5)  # renders without touching any of them
    # The same patches do fire on a spec that asks for motion: the test can fail.
    demo = load_scene("demo", scale=0.25)
    with pytest.raises(AssertionError, match="effect"):
        demo.render_gt(demo.cameras[0], 0.5)


def test_light_change_effect():
    spec = json.loads(builtin_spec_path("static_matte").read_text())
    spec["lighting"]["change"] = {"amplitude": 0.3, "period": 0.5}
    scene = SyntheticScene(spec, scale=0.2, supersample=1)
    assert scene.effects == {"light_change"}
    a, da = scene.render_gt(scene.cameras[0], 0.0)
    b, db = scene.render_gt(scene.cameras[0], 0.4)
    np.testing.assert_array_equal(da, db)  # geometry static
    assert np.abs(a - b).mean() > 0.02  # appearance changes


def test_specular_highlight_brightens():
    spec = json.loads(builtin_spec_path("static_matte").read_text())
    glossy = copy.deepcopy(spec)
    for o in glossy["objects"]:
        if o["type"] == "sphere":
            o["specular"] = {"strength": 1.0, "shininess": 8}
    a = SyntheticScene(spec, scale=0.5, supersample=1).frame(0, 5)
    b = SyntheticScene(glossy, scale=0.5, supersample=1).frame(0, 5)
    assert np.all(b >= a - 1e-6) and (b - a).max() > 0.1


def test_demo_textures_have_detail_for_stereo():
    """Most 7x7 windows have enough contrast for a photometric (ZNCC) cost to be defined."""
    import cv2

    scene = load_scene("demo")
    g = scene.frame(0, 5).mean(2)
    mean = cv2.blur(g, (7, 7))
    var = cv2.blur(g * g, (7, 7)) - mean * mean
    assert np.mean(np.sqrt(np.maximum(var, 0)) > 0.02) > 0.9


def test_bad_specs_name_the_key(tmp_path):
    spec = json.loads(builtin_spec_path("tiny").read_text())
    cases = [
        (lambda s: s.pop("objects"), "objects"),
        (lambda s: s["objects"].append({"type": "torus"}), r"objects\[4\]"),
        (lambda s: s["objects"][2].update(size=[1, -1, 1]), "size"),
        (lambda s: s["objects"][0].update(texture={"kind": "plaid"}), "texture"),
        (lambda s: s["objects"][3].update(motion={"kind": "path", "keys": [[1, 0, 0, 0], [0, 1, 1, 1]]}), "keys"),
        (lambda s: s["rig"].update(layout="sphere"), "layout"),
        (lambda s: s["rig"].update(train=[0, 1, 99]), "train"),
        (lambda s: s.update(frames=0), "frames"),
    ]
    for mutate, key in cases:
        bad = copy.deepcopy(spec)
        mutate(bad)
        path = tmp_path / "bad.json"
        path.write_text(json.dumps(bad))
        with pytest.raises(InputError, match=key) as info:
            load_scene(path)
        assert "bad.json" in str(info.value)
    path.write_text("{not json")
    with pytest.raises(InputError, match="not valid JSON"):
        load_scene(path)


def test_load_scene_errors(tmp_path):
    with pytest.raises(InputError, match="no such file"):
        load_scene(tmp_path / "missing")
    (tmp_path / "notes.txt").write_text("x")
    with pytest.raises(InputError, match="not a directory or a .json"):
        load_scene(tmp_path / "notes.txt")
    with pytest.raises(InputError, match="unknown scene layout"):
        load_scene(tmp_path)
    with pytest.raises(InputError, match="file not found"):
        load_scene(tmp_path / "absent.json")


def test_split_override_and_builtin_name_precedence(tmp_path, monkeypatch):
    scene = load_scene("tiny", train_ids=[1, 2, 4, 5])
    assert scene.train_ids == [1, 2, 4, 5] and scene.test_ids == [0, 3, 6, 7]
    # a camera in both lists is refused when the scene opens (it used to vanish from the held-out set)
    with pytest.raises(InputError, match=r"\['cam07'\] are both train and held-out"):
        load_scene("tiny", train_ids=[0, 7], test_ids=[3, 7])
    with pytest.raises(InputError, match="camera id 8"):
        load_scene("tiny", train_ids=[0, 8])
    # A folder called "demo" in the working directory does not shadow the bundled spec.
    (tmp_path / "demo").mkdir()
    monkeypatch.chdir(tmp_path)
    assert isinstance(load_scene("demo"), SyntheticScene)
    with pytest.raises(InputError, match="unknown scene layout"):
        load_scene("./demo")
