"""Files in and out: File menu, open a run folder / model file / model version, save a new
model version, reopen it (the session remembers the version), outputs land in the run folder."""
from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from app.sources import app_services

from app.sources import open_source
from app.viewer import Viewer
from fixer4d.model.io import load_model, save_ply
from fixer4d.scene import load_scene
from viewer_helpers import DEFAULT_WINDOW, Driver, gl_ctx, scene_gaussians  # noqa: F401 (fixture)

pytestmark = pytest.mark.gl


@pytest.fixture
def run(tmp_path):
    """A run folder for the tiny scene with a model_final.ply."""
    run = tmp_path / "run"
    run.mkdir()
    (run / "config.json").write_text(json.dumps({"scene": {"source": "tiny"}}))
    g = scene_gaussians(load_scene("tiny"), stride=8)
    save_ply(g.to_model(), run / "model_final.ply")
    return run


def _open(gl_ctx, source):
    src, g, session_dir = open_source(str(source))
    from app.sources import initial_state

    v = Viewer(gl_ctx, initial_state(src, g), src, services=app_services(), session_path=session_dir / "session.json")
    d = Driver(v, gl_ctx, DEFAULT_WINDOW)
    d.frame(2)
    return d


def test_save_version_through_the_menu_and_reopen(gl_ctx, run, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # nothing may land in the working directory
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "cfg"))
    d = _open(gl_ctx, run)
    v = d.viewer
    n = v.state.gaussians.n
    assert v.source.model_path == run / "model_final.ply"
    assert not v.state.show_frusta and not v.state.show_trajectories  # a run shows the model first
    sel = np.zeros(n, bool)
    sel[: n // 3] = True
    v.state.set_selection(sel)
    v.state.delete_selected()
    d.frame()
    d.click_item("menu_file")
    d.click_item("menu_save_version")
    edit = run / "model_edit_1.ply"
    assert edit.is_file() and load_model(edit).num_gaussians == n - n // 3
    assert v.state.model_version == "model_edit_1.ply" and str(edit) in v.state.status
    # a relative export path lands in the run folder
    v._traj_ui["preset"] = "viewer/my_preset.json"
    d.frame()
    d.click_item("export_preset")
    assert (run / "viewer" / "my_preset.json").is_file()
    assert {p.name for p in tmp_path.iterdir()} <= {"run", "cfg"}
    v.close()
    assert json.loads((run / "viewer" / "session.json").read_text())["model_version"] == "model_edit_1.ply"

    # reopening the run shows the saved edit; the version menu lists both
    d = _open(gl_ctx, run)
    v = d.viewer
    assert v.state.gaussians.n == n - n // 3 and v.source.model_path == edit
    assert [p.name for p in v.model_versions()] == ["model_final.ply", "model_edit_1.ply"]
    v.open_version(run / "model_final.ply")
    assert v.state.gaussians.n == n
    v.close()
    assert json.loads((run / "viewer" / "session.json").read_text())["model_version"] == "model_final.ply"


def test_open_model_files_and_the_open_dialog(gl_ctx, run, tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "cfg"))
    # fixer4d-view MODEL.ply: inside a run it brings the run's scene, alone it opens bare
    src, g, _ = open_source(str(run / "model_final.ply"))
    assert src.scene is not None and src.run_dir == run and g.n == load_model(run / "model_final.ply").num_gaussians
    bare = tmp_path / "bare"
    bare.mkdir()
    shutil.copy(run / "model_final.ply", bare / "m.ply")
    src, g, session_dir = open_source(str(bare / "m.ply"))
    assert src.scene is None and src.model_path == bare / "m.ply" and g.n > 0
    assert tmp_path / "cfg" in session_dir.parents

    d = _open(gl_ctx, bare / "m.ply")
    v = d.viewer
    assert v.output_dir == bare
    # File > Open with a bad path: the dialog says so, the notifications too, the app goes on
    for bad in (str(tmp_path / "missing.ply"), str(tmp_path / "cfg"), str(bare / "m.ply") + ".txt"):
        errors = v.notifications.errors
        d.click_item("menu_file")
        d.click_item("menu_open")
        v._file_ui["path"] = bad
        d.frame()
        d.click_item("dialog_ok")
        assert v.notifications.errors == errors + 1 and v._file_ui["error"], bad
        d.frame()
        imgui_escape(d)
    assert v.source.model_path == bare / "m.ply"
    # a good path: the run folder replaces the bare model, with its scene
    d.click_item("menu_file")
    d.click_item("menu_open")
    v._file_ui["path"] = str(run)
    d.frame()
    d.click_item("dialog_ok")
    d.frame(2)
    assert v.source.run_dir == run and v.source.scene is not None
    assert v.session_path == run / "viewer" / "session.json"
    d.settle()
    assert v.splats.gaussians is v.state.gaussians
    v.close()


def imgui_escape(d) -> None:
    """Press Escape (closes the modal dialog)."""
    from imgui_bundle import imgui

    io = imgui.get_io()
    io.add_key_event(imgui.Key.escape, True)
    d.frame()
    io.add_key_event(imgui.Key.escape, False)
    d.frame()


def test_run_restorer_kind_and_fallback(run, tmp_path):
    from app.sources import make_jobs, make_restore
    from fixer4d.errors import InputError

    cfg = json.loads((run / "config.json").read_text())
    (run / "config.json").write_text(json.dumps({**cfg, "restorer": {"kind": "learned"}}))
    with pytest.raises(InputError, match="learned restorer"):
        make_jobs("learned", None, run)  # no RUN/restorer weights
    cache, queue = make_restore(run / "cache", run)
    try:
        assert queue.kind == "warp"  # the run's learned restorer is not trained: warp instead
        queue.set_jobs(make_jobs("warp", cache, run), "warp")
        assert queue.kind == "warp" and len(queue._retired) == 1
    finally:
        queue.shutdown()
