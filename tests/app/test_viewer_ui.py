"""The viewer driven like a user: headless EGL, imgui into a framebuffer, input through io."""
from __future__ import annotations

import numpy as np
import pytest

from app.state import AppState
from app.viewer import ViewerSource
from viewer_helpers import gl_ctx, make_gaussians, make_viewer  # noqa: F401 (fixtures)

pytestmark = pytest.mark.gl


def _state(g, num_frames=20):
    st = AppState(num_frames=num_frames)
    st.view.look_from([0.0, 0.0, -4.0], [0.0, 0.0, 0.0], scene_radius=1.5)
    st.set_gaussians(g)
    return st


def _pixel(cam, point):
    uv, _ = cam.project(np.asarray(point, float)[None])
    return int(uv[0, 1]), int(uv[0, 0])  # row, col


def test_scrubbing_changes_moving_object_not_background(make_viewer):
    g = make_gaussians()
    d = make_viewer(_state(g), ViewerSource(label="test"))
    v = d.viewer
    cam = v.render_camera
    before = v.splats.read_rgb()
    assert v.state.frame == 0
    d.click_item("frame_slider", fx=0.95)
    assert v.state.frame >= 15, v.state.frame
    d.settle()
    after = v.splats.read_rgb()
    assert v.render_camera.c2w.tobytes() == cam.c2w.tobytes()  # only the time changed
    t0, t1 = 0.0, v.state.time
    for t_obj in (t0, t1):  # where the blob is at either time, the image changed
        r, c = _pixel(cam, [-0.8 + 1.6 * (t_obj - 0.5), 0.0, -0.8])
        assert np.abs(after[r, c] - before[r, c]).max() > 0.2
    # the static wall far from the blob's sweep is untouched
    wall = np.zeros(before.shape[:2], bool)
    for corner in ([-1.2, -1.2, 0.0], [1.2, 1.2, 0.0], [-1.2, 1.2, 0.0], [1.2, -1.2, 0.0]):
        r, c = _pixel(cam, corner)
        wall[r - 3:r + 4, c - 3:c + 4] = True
    assert np.abs(after - before)[wall].max() < 1e-6
    assert np.abs(before[wall]).max() > 0.05  # and there is something drawn there


def test_box_select_delete_and_undo(make_viewer):
    g = make_gaussians()
    d = make_viewer(_state(g), ViewerSource(label="test"))
    v = d.viewer
    d.click_item("tool_box")
    assert v.tool == "box"
    x0, y0, w, h = v.viewport_rect
    box = (x0 + 0.30 * w, y0 + 0.30 * h, x0 + 0.55 * w, y0 + 0.60 * h)
    d.drag(*box)
    # what should be selected: centres at the current time projecting inside the box
    uv, _ = v.render_camera.project(g.means_at(v.state.time))
    lo = np.array([box[0] - x0, box[1] - y0])
    hi = np.array([box[2] - x0, box[3] - y0])
    expected = np.all((uv >= lo) & (uv <= hi), axis=1)
    assert 0 < expected.sum() < g.n
    np.testing.assert_array_equal(v.state.selection, expected)
    d.click_item("delete")
    assert v.state.gaussians.n == g.n - expected.sum()
    assert v.state.gaussians.equals(g.subset(~expected))
    d.frame()
    assert v.splats.gaussians.n == g.n - expected.sum()  # the GL view shows the edit
    d.click_item("undo")
    assert v.state.gaussians.equals(g)
    np.testing.assert_array_equal(v.state.selection, expected)
    assert v.state.redo()
    assert v.state.gaussians.equals(g.subset(~expected))
