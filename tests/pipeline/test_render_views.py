"""render_views renders coinciding cameras once (a clip's endpoints are the reference cameras)."""
from types import SimpleNamespace

import numpy as np
import torch

import fixer4d.render.views as views
from fixer4d.pipeline.restoration import make_request
from fixer4d.render.views import render_views
from fixer4d.scene import load_scene


class _Model:
    def at(self, t, camera_center=None):
        return None


def _fake_render(calls):
    def render(snap, cam, background=None, backend="auto"):
        calls.append(cam.name)
        h, w = cam.height, cam.width
        v = float(len(calls))
        return SimpleNamespace(rgb=torch.full((h, w, 3), 0.1), depth=torch.full((h, w), v), alpha=torch.ones(h, w))
    return render


def test_coinciding_cameras_are_rendered_once(monkeypatch):
    scene = load_scene("tiny")
    calls = []
    monkeypatch.setattr(views, "render", _fake_render(calls))
    a, b = scene.train_cameras[:2]
    rgb, depth, alpha = render_views(_Model(), [a, b, a.with_pose(a.c2w.copy())], 0.0)
    assert len(calls) == 2 and rgb.shape[0] == 3
    np.testing.assert_array_equal(depth[2], depth[0])
    assert not np.array_equal(depth[1], depth[0])


def test_a_request_renders_each_distinct_view_once(monkeypatch):
    from fixer4d.geometry.trajectory import scene_trajectories

    scene = load_scene("tiny")
    calls = []
    monkeypatch.setattr(views, "render", _fake_render(calls))
    tr = scene_trajectories(scene.train_cameras, 5, arcs=False)[0]
    ids = (scene.train_ids[tr.pair[0]], scene.train_ids[tr.pair[1]])
    req = make_request(_Model(), scene, tr.cameras, 0, ids)
    # 5 clip frames (endpoints = the references) + 2 other train cameras' depth
    assert len(calls) == 5 + 2
    np.testing.assert_array_equal(req.ref_depths[0], req.depth[0])
    np.testing.assert_array_equal(req.ref_depths[1], req.depth[-1])
    assert len(req.extra_depths) == 2
