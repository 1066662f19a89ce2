"""Nothing lost: unsaved edits ask on close (save / discard / cancel), File > Quit, and the
autosave of the edits in the run folder is offered back at the next launch."""
from __future__ import annotations

import json

import numpy as np
import pytest

import app.document as document
from app.sources import app_services, initial_state
from app.viewer import Viewer, ViewerSource
from doc_shots import save_shot
from fixer4d.model.io import load_model, save_ply
from viewer_helpers import DEFAULT_WINDOW, Driver, gl_ctx, make_gaussians  # noqa: F401 (fixture)

pytestmark = pytest.mark.gl


def _open(gl_ctx, model, session, tmp_path):
    from app.gaussians import GaussianArrays

    src = ViewerSource(label=str(model), model_path=model, run_dir=model.parent)
    st = initial_state(src, GaussianArrays.from_model(load_model(model)))
    st.view.look_from([0.0, 0.0, -4.0], [0.0, 0.0, 0.0], scene_radius=1.5)
    v = Viewer(gl_ctx, st, src, services=app_services(config_dir=tmp_path / "config"), session_path=session)
    d = Driver(v, gl_ctx, DEFAULT_WINDOW)
    d.frame(2)
    return d


def test_close_with_edits_asks_and_the_autosave_comes_back(gl_ctx, tmp_path, monkeypatch):
    monkeypatch.setattr(document, "AUTOSAVE_DELAY_S", 0.0)
    run = tmp_path / "run"
    run.mkdir()
    model = run / "model_final.ply"
    save_ply(make_gaussians(n_static=100, n_moving=20).to_model(), model)
    session = run / "viewer" / "session.json"
    d = _open(gl_ctx, model, session, tmp_path)
    v, st = d.viewer, d.viewer.state
    try:
        assert not st.unsaved and v.request_close() and v.quit_confirmed  # nothing to lose: closes
        v.quit_confirmed = False
        n = st.gaussians.n
        x0, y0, w, h = v.viewport_rect
        v.select_box(0.0, 0.0, 0.5 * w, h, through=True)
        removed = st.delete_selected()
        assert 0 < removed < n and st.unsaved
        d.frame(2)
        autosave = run / "viewer" / "autosave.json"
        saved = json.loads(autosave.read_text())  # written in the run folder a moment after the edit
        assert saved["base"] == str(model) and len(saved["keep"]) == n - removed
        d.click_item("menu_file")
        d.click_item("menu_quit")  # File > Quit with unsaved edits: the prompt, no quit
        d.frame(2)
        assert v.close_prompt and not v.quit_confirmed and "close_cancel" in v.item_rects
        save_shot(v.screenshot(d.fbo), "viewer_close_prompt", tmp_path)
        d.click_item("close_cancel")
        d.frame()
        assert not v.close_prompt and not v.quit_confirmed and st.unsaved
        edited = st.gaussians
    finally:
        v.close()  # like a killed session: the edits stay in the autosave
    assert autosave.is_file()
    d = _open(gl_ctx, model, session, tmp_path)  # the next launch offers them back
    v, st = d.viewer, d.viewer.state
    try:
        assert v.autosave_offer is not None and st.gaussians.n == n
        d.frame(2)
        save_shot(v.screenshot(d.fbo), "viewer_autosave_prompt", tmp_path)
        d.click_item("autosave_restore")
        d.frame()
        assert st.gaussians.equals(edited) and st.unsaved
        st.undo()  # the restore is one undoable edit
        assert st.gaussians.n == n
        st.redo()
        v.request_close()
        d.frame(2)
        d.click_item("close_save")  # save: a new model version, then quit
        d.frame()
        assert v.quit_confirmed
        assert np.allclose(load_model(run / "model_edit_1.ply").means.detach().numpy(), edited.means, atol=1e-6)
        d.frame(2)
        assert not autosave.exists()  # saved: nothing left to restore
    finally:
        v.close()


def test_discard_quits_without_saving_and_drops_the_autosave(gl_ctx, tmp_path, monkeypatch):
    monkeypatch.setattr(document, "AUTOSAVE_DELAY_S", 0.0)
    model = tmp_path / "m.ply"
    save_ply(make_gaussians(n_static=100, n_moving=20).to_model(), model)
    d = _open(gl_ctx, model, tmp_path / "viewer" / "session.json", tmp_path)
    v = d.viewer
    try:
        st = v.state
        st.set_selection(np.arange(st.gaussians.n) < 10)
        st.delete_selected()
        d.frame(2)
        assert (tmp_path / "viewer" / "autosave.json").is_file()
        assert not v.request_close()
        d.frame(2)
        d.click_item("close_discard")
        d.frame()
        assert v.quit_confirmed and not (tmp_path / "viewer" / "autosave.json").exists()
        assert not list(tmp_path.glob("model_edit_*.ply"))
    finally:
        v.close()
    assert not (tmp_path / "viewer" / "autosave.json").exists()
