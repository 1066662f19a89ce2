"""Nothing moves under the pointer and nothing is lost by a click: a finished video render
leaves every control of the Trajectories panel where it was (a click where "render video" was
deletes no trajectory), a long path stays on one line, and every destructive action is undoable
and says so."""
from __future__ import annotations

import threading
from pathlib import Path

import numpy as np
import pytest

from app.sources import app_services, initial_state
from app.state import UNDO_HINT
from app.viewer import ViewerSource
from fixer4d.scene import load_scene
from viewer_helpers import DEFAULT_WINDOW, gl_ctx, make_viewer, scene_gaussians  # noqa: F401 (fixtures)

pytestmark = pytest.mark.gl
# The Trajectories panel's controls that must keep their place.
TRAJECTORY_ITEMS = ("render_video", "delete_trajectory", "export_preset", "import_preset", "export_camera_path",
                    "import_camera_path")


@pytest.fixture(scope="module")
def tiny():
    return load_scene("tiny")


def _places(v) -> dict[str, tuple]:
    return {name: v.item_rects[name] for name in TRAJECTORY_ITEMS}


def test_a_finished_render_moves_nothing_and_a_click_where_render_video_was_deletes_nothing(make_viewer, tiny,
                                                                                           tmp_path, monkeypatch):
    gate = threading.Event()

    def gated_video(render_fn, cameras, times, out, *, fps, progress, should_stop):
        progress(0.5)
        gate.wait(60)
        Path(out).write_bytes(b"video")
        progress(1.0)
        return Path(out)

    src = ViewerSource(scene=tiny, label="tiny", run_dir=tmp_path / "a_run_folder_with_a_long_name" / ("x" * 60))
    st = initial_state(src, scene_gaussians(tiny, stride=8))
    st.selected_trajectory = 0
    d = make_viewer(st, src, size=DEFAULT_WINDOW, services=app_services(render_video=gated_video))
    v = d.viewer
    d.frame()
    before, names = _places(v), [t.name for t in st.trajectories]
    d.click_item("render_video")
    job = v.__dict__["_video_ui"]["job"]
    d.frame(2)
    assert job.running and "video_cancel" in v.item_rects
    assert _places(v) == before  # the progress bar has its own line
    gate.set()
    job.wait(60)
    d.frame(2)
    assert job.result is not None and "video_open" in v.item_rects
    assert _places(v) == before  # the result's (long) path too
    # "open video" on a machine without a desktop opener: where the file is, its path copied
    from imgui_bundle import imgui

    import app.desktop

    monkeypatch.setattr(app.desktop.shutil, "which", lambda name: None)
    d.click_item("video_open")
    assert "no desktop opener" in st.status and str(job.result) in st.status and "copied" in st.status
    assert imgui.get_clipboard_text() == str(job.result)
    assert _places(v) == before
    rx0, ry0, rx1, ry1 = before["render_video"]
    d.click((rx0 + rx1) / 2, (ry0 + ry1) / 2)  # where "render video" was (and still is)
    d.frame()
    assert [t.name for t in st.trajectories] == names  # no trajectory deleted
    assert v.__dict__["_video_ui"]["job"] is not job  # the click rendered again, as it says
    # a long path typed into a file field stays on one line: the buttons under it stay put
    v._traj_ui["preset"] = "/" + "/".join(["a_folder_with_a_long_name"] * 12) + "/trajectories.json"
    d.frame(2)
    assert _places(v) == before


def test_every_destructive_action_is_undoable_and_says_so(make_viewer, tiny, tmp_path):
    from app import trajectories as traj

    src = ViewerSource(scene=tiny, label="tiny", run_dir=tmp_path)
    st = initial_state(src, scene_gaussians(tiny, stride=8))
    st.selected_trajectory = 1
    d = make_viewer(st, src, size=DEFAULT_WINDOW)
    v = d.viewer
    d.frame()

    def undone(before) -> None:
        assert UNDO_HINT in st.status, st.status
        d.frame()
        assert v.item_rects["status_line"][2] > v.item_rects["status_line"][0]  # shown in the status line
        d.press("z", ctrl=True)
        assert before() and st.status.startswith("undo:"), st.status

    names = [t.name for t in st.trajectories]
    d.click_item("delete_trajectory")
    assert [t.name for t in st.trajectories] == names[:1] + names[2:]
    undone(lambda: [t.name for t in st.trajectories] == names)

    n = st.gaussians.n
    for button in ("delete", "isolate"):
        mask = np.zeros(n, bool)
        mask[: n // 3] = True
        st.set_selection(mask)
        d.frame()
        d.click_item(button)
        assert st.gaussians.n == (n - n // 3 if button == "delete" else n // 3)
        undone(lambda: st.gaussians.n == n)

    preset = traj.save_preset(tmp_path / "two.json", st.trajectories[:2], tiny.train_cameras)
    v._traj_ui["preset"] = str(preset)
    d.frame()
    d.click_item("import_preset")  # replaces the whole list
    assert len(st.trajectories) == 2
    undone(lambda: [t.name for t in st.trajectories] == names)

    # discarding edits is never silent: closing with unsaved edits asks first
    d.click_item("delete_trajectory")
    mask = np.zeros(st.gaussians.n, bool)
    mask[:5] = True
    st.set_selection(mask)
    st.delete_selected()
    d.frame()
    assert not v.request_close() and not v.quit_confirmed
    d.frame(2)
    assert "close_discard" in v.item_rects and not v.quit_confirmed


def test_jobs_that_change_state_move_no_control(make_viewer, tiny, tmp_path):
    """A restoration that fails (its error line) and live training going from setup to running
    to failed leave the Restore and Training panels' controls where they were."""
    from ui_walk import busy_viewer

    d = busy_viewer(make_viewer, tiny, tmp_path, DEFAULT_WINDOW)
    v = d.viewer
    v.show_help = v.show_report = v.show_notifications = False
    failed, running = v.source.restore.items  # shown newest first: running, then failed
    tr = v.source.training
    tr.state, tr.setup_started, tr.setup_status = "setup", None, "init: mvs point clouds of every 2nd frame"
    d.frame(2)
    corner = lambda name: v.item_rects[name][:2]  # noqa: E731 (x0, y0)
    before = {name: corner(name) for name in ("restore_cancel_0", "restore_cancel_1", "training_control")}
    running.status, running.error = "failed", "a long error from the restorer " * 4
    tr.state, tr.error = "running", None
    d.frame(2)
    assert {name: corner(name) for name in before} == before
    tr.state, tr.error = "failed", "RuntimeError: out of memory at step 20"
    d.frame(2)
    assert {name: corner(name) for name in ("restore_cancel_0", "restore_cancel_1")} == {
        name: before[name] for name in ("restore_cancel_0", "restore_cancel_1")}
