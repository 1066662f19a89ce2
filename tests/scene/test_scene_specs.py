"""The bundled specs that call for different effects: slow_rigid (matte, slow rigid motion) and
fast_thin (fast thin objects, a view-dependent highlight)."""
from __future__ import annotations

import copy

import numpy as np
import pytest

from fixer4d.scene import load_scene
from fixer4d.scene.synthetic import SyntheticScene


def _consecutive_iou(scene, cam: int) -> float:
    """Mean IoU of the exact moving masks of consecutive frames: near 1 for slow motion, near 0
    when objects move more than their own width per frame."""
    masks = [scene.moving_mask(f, cam) for f in range(scene.num_frames)]
    ious = [(a & b).sum() / max((a | b).sum(), 1) for a, b in zip(masks, masks[1:])]
    return float(np.mean(ious))


@pytest.mark.parametrize("name", ["slow_rigid", "fast_thin"])
def test_specs_load_by_name_and_stay_small(name):
    scene = load_scene(name)
    assert isinstance(scene, SyntheticScene) and scene.name == name
    assert len(scene.train_ids) == 4 and scene.test_ids
    cam = scene.cameras[0]
    assert cam.width * cam.height <= 128 * 96 and scene.num_frames <= 12
    # Something moves and is seen by every train camera at some frame.
    for c in scene.train_ids:
        assert any(scene.moving_mask(f, c).any() for f in range(scene.num_frames))


def test_slow_rigid_is_matte_with_slow_motion():
    scene = load_scene("slow_rigid")
    assert scene.effects == frozenset({"motion"})
    assert all(o.specular is None for o in scene.world.objects)
    assert all(_consecutive_iou(scene, c) > 0.7 for c in scene.train_ids)


def test_fast_thin_has_fast_thin_motion_and_a_highlight():
    scene = load_scene("fast_thin")
    assert {"motion", "specular"} <= scene.effects
    assert all(_consecutive_iou(scene, c) < 0.4 for c in scene.train_ids)
    # Thin: the moving objects cover a small share of the image although they sweep across it.
    cam = scene.train_ids[0]
    masks = np.stack([scene.moving_mask(f, cam) for f in range(scene.num_frames)])
    assert masks.mean() < 0.05 and masks.any(0).mean() > 2 * masks.mean()
    # A highlight a matte render lacks: the same spec without "specular" is darker somewhere.
    matte = copy.deepcopy(scene.spec)
    for o in matte["objects"]:
        o.pop("specular", None)
    plain = SyntheticScene(matte, supersample=1)
    f = 0
    highlight = {}
    a, b = scene.train_ids[0], scene.train_ids[-1]  # diagonal corners: the widest baseline
    for c in (a, b):
        lit = scene.render_gt(scene.cameras[c], scene.time(f), supersample=1)[0]
        base = plain.render_gt(plain.cameras[c], plain.time(f), supersample=1)[0]
        highlight[c] = (lit - base).max(-1)
        assert highlight[c].max() > 0.2
    # View-dependent: the surface point brightest in one train camera is much less bright, or
    # not lit at all, seen from the opposite corner of the rig.
    v, u = np.unravel_index(np.argmax(highlight[a]), highlight[a].shape)
    X = scene.cameras[a].backproject(np.array([[u + 0.5, v + 0.5]]), np.array([scene.depth(f, a)[v, u]]))
    uv, _ = scene.cameras[b].project(X)
    ub, vb = int(uv[0, 0]), int(uv[0, 1])
    assert highlight[b][vb, ub] < 0.5 * highlight[a][v, u]
