"""Robust panels: every import field fed bad files (truncated, wrong schema, missing) through
the UI, and a panel that fails with windows/stacks open; the app must keep drawing, report the
error in its notifications area, and keep every panel working."""
from __future__ import annotations

import json

import numpy as np
import pytest
from imgui_bundle import imgui

from app.sources import initial_state
from app.viewer import ViewerSource
from fixer4d.scene import load_scene
from viewer_helpers import DEFAULT_WINDOW, gl_ctx, make_viewer  # noqa: F401 (fixtures)

pytestmark = pytest.mark.gl


@pytest.fixture(scope="module")
def tiny():
    return load_scene("tiny")


def bad_files(tmp_path, good: str) -> dict[str, str]:
    """A missing path, a truncated copy of a good file, a JSON of the wrong schema, binary junk."""
    (tmp_path / "truncated.json").write_text(good[: len(good) // 2])
    (tmp_path / "schema.json").write_text(json.dumps({"frames": "no", "trajectories": 3, "camera_path": [1, 2]}))
    (tmp_path / "list.json").write_text(json.dumps([1, 2, 3]))
    (tmp_path / "junk.json").write_bytes(bytes(range(256)))
    return {"missing": str(tmp_path / "nope" / "missing.json"), "truncated": str(tmp_path / "truncated.json"),
            "schema": str(tmp_path / "schema.json"), "list": str(tmp_path / "list.json"),
            "junk": str(tmp_path / "junk.json"), "folder": str(tmp_path)}


def assert_responsive(d) -> None:
    """The UI still reacts to input: scrubbing the timeline changes the frame."""
    st = d.viewer.state
    st.set_frame(0)
    d.frame()
    d.click_item("frame_slider", fx=0.9)
    assert st.frame > 0


def test_bad_imports_are_reported_and_the_app_keeps_running(make_viewer, tiny, tmp_path):
    from app import trajectories as traj

    src = ViewerSource(scene=tiny, label="tiny")
    st = initial_state(src, None)  # no model: fast frames; the panels are what is tested
    d = make_viewer(st, src, size=DEFAULT_WINDOW)
    v = d.viewer
    good_preset = traj.save_preset(tmp_path / "good_preset.json", st.trajectories, tiny.train_cameras).read_text()
    good_path = traj.save_camera_path(tmp_path / "good_path.json", st.trajectories[0], tiny.train_cameras, 0.1)
    before = list(st.trajectories)
    fields = [("preset", "import_preset", good_preset), ("camera_path", "import_camera_path", good_path.read_text())]
    for field, button, good in fields:
        for kind, path in bad_files(tmp_path / field, good).items() if (tmp_path / field).mkdir() is None else ():
            n_errors = v.notifications.errors
            v._traj_ui[field] = path
            d.frame()
            d.click_item(button)
            d.frame(2)
            assert v.notifications.errors == n_errors + 1, (field, kind)
            msg = v.notifications.last_error()
            assert msg.source == "trajectories", msg
            assert st.trajectories == before, (field, kind)  # nothing half-imported
            assert v.show_notifications
            assert_responsive(d)
    # and the good files still import through the same buttons
    v._traj_ui["preset"] = str(tmp_path / "good_preset.json")
    d.frame()
    d.click_item("import_preset")
    assert st.trajectories == before and st.undo_stack[-1].label.startswith("import")
    v._traj_ui["camera_path"] = str(good_path)
    d.frame()
    d.click_item("import_camera_path")
    assert len(st.trajectories) == len(before) + 1


def test_panel_failing_with_open_stacks_is_recovered(make_viewer, tiny, capfd):
    src = ViewerSource(scene=tiny, label="tiny")
    st = initial_state(src, None)  # no model: fast frames; the panels are what is tested
    d = make_viewer(st, src)
    v = d.viewer
    calls = {"n": 0}

    def broken(viewer) -> None:
        from app.panels._layout import panel

        with panel(viewer, "broken", "Broken", 10, 10, 200, 200) as expanded:
            if expanded:
                calls["n"] += 1
                imgui.begin_child("child", imgui.ImVec2(100, 100))
                imgui.push_id("x")
                imgui.begin_group()
                imgui.push_style_color(imgui.Col_.text.value, imgui.ImVec4(1, 0, 0, 1))
                imgui.begin_disabled(True)
                if not calls.get("fixed"):
                    raise ValueError("broken on purpose")
                imgui.end_disabled()
                imgui.pop_style_color()
                imgui.end_group()
                imgui.pop_id()
                imgui.end_child()

    v.panels = [*v.panels[:2], ("broken", broken), *v.panels[2:]]
    capfd.readouterr()
    d.frame(3)
    assert calls["n"] >= 3
    out, err = capfd.readouterr()  # the caught error is reported once, not as imgui's stack lines every frame
    assert "[imgui-error]" not in out + err and "Missing End" not in out + err, (out + err)[-500:]
    # reported once although it fails every frame, and the panels after it still draw
    assert [m.text for m in v.notifications.items() if m.source == "broken"] == ["ValueError: broken on purpose"]
    assert v.panel_errors["broken"] == "ValueError: broken on purpose"
    assert "trajectories" not in v.panel_errors and "frame_slider" in v.item_rects
    assert_responsive(d)
    shot = v.screenshot(d.fbo)
    assert shot.std() > 5.0  # the window was drawn
    calls["fixed"] = True
    d.frame(2)
    assert "broken" not in v.panel_errors  # drawing cleanly again clears its error
    assert np.isfinite(v.frame_ms)
