"""The demo's validation cameras (bundled spec ``demo_val``): the demo scene with its own train
cameras and held-out cameras none of the demo's test cameras occupy, so settings chosen on them
leave the demo's reported rows (its 12 held-out cameras) untouched."""
from __future__ import annotations

import numpy as np

from fixer4d.pipeline.other_cameras import check_same_train_cameras
from fixer4d.scene import load_scene
from fixer4d.scene.synthetic import read_spec

# A validation camera closer than this to a demo test camera would nearly repeat it: half the
# demo grid's smaller spacing (0.2 world units between rows).
MIN_DISTANCE_TO_A_TEST_CAMERA = 0.1
# Small render so the pixel check stays fast: 1/4 of 200x150 and 2 of the 20 frames.
SCALE, FRAMES = 0.25, (0, 2)


def test_the_spec_is_the_demo_plus_cameras():
    demo, _ = read_spec("demo")
    val, _ = read_spec("demo_val")
    rig_keys = {"extra", "train", "test"}
    assert {k: v for k, v in val.items() if k not in ("name", "description", "rig")} == \
        {k: v for k, v in demo.items() if k not in ("name", "description", "rig")}
    assert {k: v for k, v in val["rig"].items() if k not in rig_keys} == \
        {k: v for k, v in demo["rig"].items() if k not in rig_keys}


def test_train_cameras_are_the_demos():
    demo, val = load_scene("demo"), load_scene("demo_val")
    assert val.train_ids == demo.train_ids
    for i in demo.train_ids:
        a, b = demo.cameras[i], val.cameras[i]
        assert np.array_equal(a.K, b.K) and np.array_equal(a.c2w, b.c2w) and (a.width, a.height) == (b.width, b.height)
    small = dict(scale=SCALE, frame_range=FRAMES)
    check_same_train_cameras(load_scene("demo", **small), load_scene("demo_val", **small))


def test_validation_cameras_are_not_test_cameras():
    demo, val = load_scene("demo"), load_scene("demo_val")
    assert 6 <= len(val.test_ids) <= 9
    test_centres = np.stack([demo.cameras[i].center for i in demo.test_ids])
    used = val.train_ids + val.test_ids
    for j in val.test_ids:
        gaps = np.linalg.norm(test_centres - val.cameras[j].center, axis=1)
        assert gaps.min() >= MIN_DISTANCE_TO_A_TEST_CAMERA, (val.cameras[j].name, gaps.min())
    # The demo's test cameras are in the rig (same numbering) but neither trained nor scored.
    assert not set(demo.test_ids) & set(used)
    # Inside the rig's volume: within the bounding box of the demo's cameras.
    all_demo = np.stack([c.center for c in demo.cameras])
    for j in val.test_ids:
        assert np.all(val.cameras[j].center >= all_demo.min(0) - 1e-9)
        assert np.all(val.cameras[j].center <= all_demo.max(0) + 1e-9)
