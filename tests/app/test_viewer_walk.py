"""What a scripted walk through the viewer (xdotool on Xvfb) found, fixed and kept fixed:
resizing the app window left the panels at their old positions (cut off when it shrank, the new
area empty when it grew): now the layout scales with it, a panel hidden during the resize
included; "add the 6 pairs + arcs" appended duplicates on every click; fly keys moved the camera
during Ctrl chords (Ctrl+S) and while typing; "Save model as" replaced the run's model_final.ply."""
from __future__ import annotations

import pytest

from app.sources import initial_state
from app.viewer import ViewerSource
from fixer4d.scene import load_scene
from viewer_helpers import DEFAULT_WINDOW, gl_ctx, make_viewer  # noqa: F401 (fixtures)

pytestmark = pytest.mark.gl


def _outer(rects) -> tuple[float, float]:
    return max(r[2] for r in rects.values()), max(r[3] for r in rects.values())


def test_panels_follow_the_window_size(make_viewer, gl_ctx):
    src = ViewerSource(scene=load_scene("tiny"), label="tiny")
    d = make_viewer(initial_state(src, None), src, size=DEFAULT_WINDOW)
    d.viewer.show_notifications = True
    d.frame(2)
    before = dict(d.viewer.window_rects)
    assert {"viewport", "compare", "restore", "notifications"} <= set(before)
    # notifications sit below the Compare panel's controls
    assert before["notifications"][1] > before["compare"][1] + 100
    d.viewer.show_notifications = False  # hidden while the window changes size
    for size in ((900, 600), (1600, 1000)):
        d.fbo = gl_ctx.simple_framebuffer(size)
        d.frame(3)
        rects = d.viewer.window_rects
        sx, sy = size[0] / DEFAULT_WINDOW[0], size[1] / DEFAULT_WINDOW[1]
        for name, (x0, y0, x1, y1) in rects.items():
            b = before[name]
            # imgui rounds positions and enforces minimum sizes: a few pixels of slack
            assert abs(x0 - b[0] * sx) <= 3 and abs(y0 - b[1] * sy) <= 3, (size, name)
            assert x1 <= size[0] + 1 and y1 <= size[1] + 1, (size, name, rects[name])
        w, h = _outer(rects)
        assert w >= 0.97 * size[0] and h >= 0.97 * size[1], (size, w, h)  # the panels fill the window
    d.viewer.show_notifications = True
    d.frame(2)
    n, b = d.viewer.window_rects["notifications"], before["notifications"]
    assert abs(n[0] - b[0] * 1600 / 1440) <= 3 and abs(n[3] - b[3] * 1000 / 900) <= 3


def test_adding_the_default_trajectories_twice_does_not_duplicate_them(make_viewer):
    src = ViewerSource(scene=load_scene("tiny"), label="tiny")
    st = initial_state(src, None)
    st.trajectories = st.trajectories[:2]  # the user deleted all but two
    d = make_viewer(st, src, size=DEFAULT_WINDOW)
    d.click_item("add_default_trajectories")
    names = [t.name for t in d.viewer.state.trajectories]
    assert len(names) == len(set(names)) == 8  # 6 pairs + 2 arcs, the two kept ones not repeated
    d.frame()
    d.click_item("add_default_trajectories")
    assert [t.name for t in d.viewer.state.trajectories] == names
    assert "already" in d.viewer.state.status


def test_fly_keys_leave_ctrl_chords_alone(make_viewer):
    """Ctrl+S (save) in fly mode also flew the camera backwards while S was held."""
    from imgui_bundle import imgui

    from viewer_helpers import scene_gaussians

    scene = load_scene("tiny")
    src = ViewerSource(scene=scene, label="tiny")
    d = make_viewer(initial_state(src, scene_gaussians(scene, stride=8)), src, size=DEFAULT_WINDOW)
    st = d.viewer.state
    st.view.mode = "fly"
    x0, y0, x1, y1 = d.viewer.window_rects["viewport"]
    d.move((x0 + x1) / 2, (y0 + y1) / 2)
    io = imgui.get_io()

    def held(keys) -> float:
        eye = st.view.eye().copy()
        for k in keys:
            io.add_key_event(k, True)
        d.frame(3)
        for k in keys:
            io.add_key_event(k, False)
        d.frame()
        return float(abs(st.view.eye() - eye).max())

    assert held([imgui.Key.mod_ctrl, imgui.Key.s]) == 0.0
    assert held([imgui.Key.s]) > 0.0  # S alone still flies


def test_save_model_as_never_replaces_a_file(make_viewer, tmp_path):
    """"Save model as" with the name of the run's model_final.ply replaced the pipeline's result."""
    from app.panels import files
    from fixer4d.model.io import save_ply
    from viewer_helpers import scene_gaussians

    scene = load_scene("tiny")
    src = ViewerSource(scene=scene, label="tiny", run_dir=tmp_path)
    st = initial_state(src, scene_gaussians(scene, stride=8))
    d = make_viewer(st, src, size=DEFAULT_WINDOW)
    final = tmp_path / "model_final.ply"
    save_ply(scene_gaussians(scene, stride=16).to_model(), final)
    before = final.read_bytes()
    with pytest.raises(ValueError, match="never replaces a file"):
        files.run_action(d.viewer, "save_model_as", str(final))
    assert final.read_bytes() == before
    assert "wrote" in files.run_action(d.viewer, "save_model_as", str(tmp_path / "mine.ply"))
    assert (tmp_path / "mine.ply").is_file()


def test_a_quick_chord_keeps_the_viewer_awake_until_it_is_read(make_viewer):
    """A Ctrl+Z sent within a few ms (macro tools, remote desktops) was dropped while the viewer
    idled: imgui spreads queued events over frames, and the window loop slept in between."""
    from imgui_bundle import imgui

    from viewer_helpers import scene_gaussians

    scene = load_scene("tiny")
    src = ViewerSource(scene=scene, label="tiny")
    d = make_viewer(initial_state(src, scene_gaussians(scene, stride=8)), src, size=DEFAULT_WINDOW)
    d.settle()
    assert d.viewer.is_idle()
    io = imgui.get_io()
    for key, down in ((imgui.Key.mod_ctrl, True), (imgui.Key.z, True), (imgui.Key.z, False), (imgui.Key.mod_ctrl, False)):
        io.add_key_event(key, down)
    frames = 0
    while not d.viewer.is_idle() and frames < 10:
        d.frame()
        frames += 1
    assert 1 <= frames < 10 and len(imgui.get_current_context().input_events_queue) == 0
