"""Input the user can trust: shortcuts on the key-press event (a 1 ms Ctrl+Z undoes), box
selection of the front surface (a box around a pillar leaves the wall behind it)."""
from __future__ import annotations

import types

import numpy as np
import pytest

from app.gaussians import GaussianArrays
from app.state import AppState
from app.viewer import ViewerSource
from doc_shots import save_shot
from viewer_helpers import gl_ctx, make_gaussians, make_viewer  # noqa: F401 (fixtures)

pytestmark = pytest.mark.gl


def _state(g):
    st = AppState(num_frames=4)
    st.view.look_from([0.0, 0.0, -4.0], [0.0, 0.0, 0.0], scene_radius=1.5)
    st.set_gaussians(g)
    return st


def test_a_1ms_ctrl_z_undoes(make_viewer):
    d = make_viewer(_state(make_gaussians(n_static=100, n_moving=20)), ViewerSource(label="test"))
    st = d.viewer.state
    n = st.gaussians.n
    st.set_selection(np.arange(n) < 10)
    st.delete_selected()
    assert st.gaussians.n == n - 10
    d.press("z", ctrl=True, frames_held=0)  # down and up before one frame: a 1 ms press
    assert st.gaussians.n == n and st.redo_stack
    d.press("y", ctrl=True, frames_held=0)
    assert st.gaussians.n == n - 10
    d.press("space", frames_held=0)
    assert st.playing


def test_the_window_key_callback_reports_presses_of_any_length():
    """app.main's glfw key callback turns PRESS/RELEASE into viewer.key_event (a press is kept
    until the frame handles it)."""
    from app.main import install_key_callback

    fake = types.SimpleNamespace(KEY_Z=90, KEY_Y=89, KEY_O=79, KEY_S=83, KEY_Q=81, KEY_SPACE=32, PRESS=1,
                                 RELEASE=0, MOD_CONTROL=2, callback=None)
    fake.set_key_callback = lambda window, fn: setattr(fake, "callback", fn)
    seen = []
    viewer = types.SimpleNamespace(key_event=lambda key, down, ctrl=False: seen.append((key, down, ctrl)))
    install_key_callback(fake, "window", [viewer])
    fake.callback("window", 90, 0, 1, 2)  # Ctrl+Z down
    fake.callback("window", 90, 0, 0, 2)  # up, a millisecond later
    fake.callback("window", 65, 0, 1, 0)  # A: no shortcut
    assert seen == [("z", True, True), ("z", False, True)]


def pillar_scene(side: int = 24) -> GaussianArrays:
    """A wall at z = 0 (x, y in [-1.5, 1.5]) and a pillar in front of it at z = -1.2
    (x in [-0.2, 0.2], y in [-1, 1]); the pillar is red, the wall grey-blue."""
    gx, gy = np.meshgrid(np.linspace(-1.5, 1.5, side), np.linspace(-1.5, 1.5, side))
    wall = np.stack([gx.ravel(), gy.ravel(), np.zeros(side * side)], 1)
    px, py = np.meshgrid(np.linspace(-0.2, 0.2, 4), np.linspace(-1.0, 1.0, 20))
    pillar = np.stack([px.ravel(), py.ravel(), np.full(px.size, -1.2)], 1)
    n_w, n_p = wall.shape[0], pillar.shape[0]
    n = n_w + n_p
    sizes = np.concatenate([np.full(n_w, 3.0 / side), np.full(n_p, 0.08)])
    colors = np.concatenate([np.tile([[-0.5, -0.2, 0.5]], (n_w, 1)), np.tile([[1.5, -1.5, -1.5]], (n_p, 1))])
    return GaussianArrays(means=np.concatenate([wall, pillar]), log_scales=np.log(np.repeat(sizes[:, None], 3, 1)),
                          quats=np.tile([1.0, 0, 0, 0], (n, 1)), opacity_logits=np.full(n, 4.0), colors=colors,
                          t_center=np.zeros(n), t_log_scale=np.full(n, 2.0), motion=np.zeros((n, 9)),
                          omega=np.zeros((n, 4)), dynamic=np.zeros(n, bool))


def test_box_select_takes_the_front_surface_not_the_wall_behind(make_viewer, tmp_path):
    g = pillar_scene()
    n_wall = g.n - 80
    d = make_viewer(_state(g), ViewerSource(label="pillar"))
    v = d.viewer
    d.settle()
    d.click_item("tool_box")
    cam = v.display_camera
    uv, _ = cam.project(g.means[n_wall:])
    lo, hi = uv.min(0) - 6.0, uv.max(0) + 6.0  # a box around the pillar, a little margin
    x0, y0, _, _ = v.viewport_rect
    d.drag(x0 + lo[0], y0 + lo[1], x0 + hi[0], y0 + hi[1])
    sel = v.state.selection
    assert sel[n_wall:].all()  # every pillar Gaussian
    wall_uv, _ = cam.project(g.means[:n_wall])
    in_box = np.all((wall_uv >= lo) & (wall_uv <= hi), axis=1)
    plo, phi = uv.min(0), uv.max(0)
    behind = np.all((wall_uv > plo + 2) & (wall_uv < phi - 2), axis=1)  # hidden by the pillar
    assert behind.sum() >= 10 and not sel[:n_wall][behind].any()  # the wall behind it is left alone
    d.settle()
    save_shot(v.screenshot(d.fbo), "viewer_box_select_front", tmp_path)
    # "through": the same box takes the hidden wall too
    d.click_item("select_through")
    assert v.select_through
    d.drag(x0 + lo[0], y0 + lo[1], x0 + hi[0], y0 + hi[1])
    assert v.state.selection[:n_wall][behind].all() and v.state.selection[:n_wall][in_box].all()
