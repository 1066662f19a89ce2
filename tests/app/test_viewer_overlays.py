"""Overlays with legends: colour bars with units for depth / speed / temporal opacity, the blur
map that follows the view (stale while it moves, recomputed when it rests), and the
moving-content mask of a run's init."""
from __future__ import annotations

import json

import numpy as np
import pytest

from app.sources import app_services

from app.legends import legend, turbo
from app.sources import initial_state, open_source
from app.viewer import Viewer, ViewerSource
from fixer4d.init.masks import save_masks
from fixer4d.model.io import save_ply
from fixer4d.scene import load_scene
from viewer_helpers import DEFAULT_WINDOW, Driver, gl_ctx, make_gaussians, make_viewer, scene_gaussians  # noqa: F401

pytestmark = pytest.mark.gl


@pytest.fixture(scope="module")
def tiny():
    return load_scene("tiny")


def _bar_pixels(d) -> tuple[np.ndarray, np.ndarray]:
    """Screen colours at the left and right ends of the drawn colour bar."""
    x0, y0, x1, y1 = d.viewer.item_rects["legend_bar"]
    shot = d.viewer.screenshot(d.fbo).astype(float)
    y = int((y0 + y1) / 2)
    return shot[y, int(x0) + 2], shot[y, int(x1) - 3]


def test_depth_and_heatmap_legends_with_units(make_viewer, tiny):
    src = ViewerSource(scene=tiny, label="tiny")
    st = initial_state(src, scene_gaussians(tiny, stride=4))
    st.show_frusta = st.show_trajectories = False
    d = make_viewer(st, src)
    v = d.viewer
    assert legend(v) is None  # plain colour: no bar
    st.debug_mode = "depth"
    d.settle()
    lg = legend(v)
    near, far = v.depth_range
    assert (lg.lo, lg.hi) == (near, far) and 0 < near < far and "scene units" in lg.title
    left, right = _bar_pixels(d)  # near is red, far is blue, as the depth image
    np.testing.assert_allclose(left, turbo(1.0) * 255, atol=12)
    np.testing.assert_allclose(right, turbo(0.0) * 255, atol=12)
    st.debug_mode = "color"
    st.splat_mode = "temporal_opacity"
    d.settle()
    lg = legend(v)
    assert (lg.lo, lg.hi) == (0.0, 1.0)
    left, right = _bar_pixels(d)
    np.testing.assert_allclose(left, turbo(0.0) * 255, atol=12)


def test_speed_legend_in_scene_units_per_second(make_viewer):
    g = make_gaussians()  # the blob moves 1.6 units per clip
    st = initial_state(ViewerSource(label="t"), g)
    st.num_frames, st.fps = 20, 10.0  # a 2 s clip: 0.8 units/s
    st.view.look_from([0.0, 0.0, -4.0], [0.0, 0.0, 0.0], scene_radius=1.5)
    st.splat_mode = "speed"
    d = make_viewer(st, ViewerSource(label="t"))
    d.settle()
    lg = legend(d.viewer)
    assert lg.hi == pytest.approx(0.8, rel=1e-3) and "per second" in lg.title


def test_blur_map_follows_the_view(make_viewer, tiny):
    src = ViewerSource(scene=tiny, label="tiny")
    st = initial_state(src, scene_gaussians(tiny, stride=4))
    st.show_frusta = st.show_trajectories = False
    d = make_viewer(st, src)
    v = d.viewer
    st.debug_mode = "blur"
    d.settle()
    assert not v.map_stale and legend(v).note == ""
    first = v.scalar_key
    v.adaptive.full_cost_ms = 1e6  # as on a slow GL: moving frames are reduced, not final
    st.view.rotate(30.0, 0.0, 400)
    d.frame()
    assert v.map_stale and "stale" in legend(v).note
    d.settle()
    assert not v.map_stale and v.scalar_key != first  # recomputed for the new view


def test_moving_mask_overlay_from_the_run(gl_ctx, tiny, tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "cfg"))
    run = tmp_path / "run"
    (run / "init_mvs").mkdir(parents=True)
    (run / "config.json").write_text(json.dumps({"scene": {"source": "tiny"}}))
    save_ply(scene_gaussians(tiny, stride=2).to_model(), run / "model_final.ply")
    cam_id = tiny.train_ids[1]
    cam = tiny.cameras[cam_id]
    masks = np.zeros((1, 2, cam.height, cam.width), bool)
    masks[0, 0, :, : cam.width // 2] = True  # the left half "moves" at frame 0
    save_masks(run / "init_mvs" / "masks.npz", masks, [str(cam_id)], [0, 2])
    src, g, _ = open_source(str(run))
    st = initial_state(src, g)
    st.view.snap_to(cam)
    st.debug_mode = "moving"
    v = Viewer(gl_ctx, st, src, services=app_services())
    d = Driver(v, gl_ctx, DEFAULT_WINDOW)
    try:
        d.settle()
        assert v.mask_note.startswith("camera ") and "frames 0" in v.mask_note  # which frames carry masks
        x0, y0, w, h = v.viewport_rect
        shot = v.screenshot(d.fbo).astype(float)
        row = int(y0 + h * 0.3)
        left, right = shot[row, int(x0 + w * 0.25)], shot[row, int(x0 + w * 0.75)]
        magenta = np.array([255.0, 51.0, 230.0])
        assert np.abs(left - magenta).sum() < np.abs(right - magenta).sum() - 60
        st.set_frame(1)  # a frame without a mask: nothing drawn, the note says why
        d.settle()
        assert v.mask_note.startswith("masks on cameras") and "frames 0" in v.mask_note
        lx0, ly0, lx1, ly1 = v.item_rects["legend_box"]  # the legend's box holds its note
        from imgui_bundle import imgui

        assert imgui.calc_text_size(v.mask_note).x <= lx1 - lx0
    finally:
        v.close()


def test_compare_shows_where_a_gated_target_is_restored():
    """A gated pseudo-target is the render but where its gate (stored as the entry's confidence)
    restores; other entries show the pixels no train camera explains."""
    from app.panels.compare import supervision_map

    conf, hidden = np.full((2, 3, 4), 0.25, np.float32), np.full((2, 3, 4), 0.75, np.float32)

    class Entry:
        def __init__(self, meta):
            self.meta = meta

        def confidence(self):
            return conf

        def unobserved(self):
            return hidden

    assert supervision_map(Entry({"pseudo_target": "gated"})) is conf
    assert supervision_map(Entry({"pseudo_target": "restored"})) is hidden
    assert supervision_map(Entry({})) is hidden
