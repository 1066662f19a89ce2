"""The undetermined overlay: where the shown model and its twin field (``co_fields``,
``model_stage1_twin.ply`` beside it) disagree. Greyed out with the way to a twin when the model
has none; computed through the injected twin renderer when the view rests (an identical twin
gives an all-zero map); its legend's scale, meaning and share of the view."""
from __future__ import annotations

import json

import numpy as np
import pytest
from imgui_bundle import imgui

from app.legends import UNDETERMINED_TITLE, legend
from app.sources import TwinRenders, app_services, initial_state, open_source
from app.undetermined import HOW_TO_GET_A_TWIN
from doc_shots import save_shot
from fixer4d.model.io import save_ply
from fixer4d.scene import load_scene
from ui_walk import Recorder
from viewer_helpers import DEFAULT_WINDOW, gl_ctx, make_viewer, scene_gaussians  # noqa: F401 (fixtures)

pytestmark = pytest.mark.gl


@pytest.fixture(scope="module")
def tiny():
    return load_scene("tiny")


def _run(tmp_path, tiny, twin=None, fields=None):
    """A run folder of the tiny scene with model_stage1.ply and, given, its twin field, or its two
    stage-1 fields (``fields(g)`` -> the second; the first is ``g``)."""
    run = tmp_path / "run"
    run.mkdir()
    (run / "config.json").write_text(json.dumps({"scene": {"source": "tiny"}}))
    g = scene_gaussians(tiny, stride=2)
    save_ply(g.to_model(), run / "model_stage1.ply")
    if twin is not None:
        save_ply(twin(g).to_model(), run / "model_stage1_twin.ply")
    if fields is not None:
        for k, field in enumerate((g, fields(g))):
            (run / "fields" / f"field{k}").mkdir(parents=True)
            save_ply(field.to_model(), run / "fields" / f"field{k}" / "model.ply")
    return run


def _open(make_viewer, run, render_twin=None, snap=True):
    src, g, _ = open_source(str(run))
    st = initial_state(src, g)
    if snap:
        st.view.snap_to(src.scene.train_cameras[1])
    services = app_services(config_dir=run / "cfg", **({} if render_twin is None else {"render_twin": render_twin}))
    return make_viewer(st, src, size=DEFAULT_WINDOW, services=services)


def _radio(d, monkeypatch) -> tuple[float, float]:
    """Screen centre of the Debug panel's "undetermined" image-mode radio button."""
    rec = Recorder(monkeypatch)
    d.frame()
    item = next(i for i in rec.items if i.kind == "radio_button" and i.label == "undetermined##image")
    x0, y0, x1, y1 = item.rect
    return (x0 + x1) / 2.0, (y0 + y1) / 2.0


def _counting(renders):
    calls = []

    def render_twin(path, background, backend):
        calls.append(path.name)
        return renders(path, background, backend)
    return render_twin, calls


def test_every_model_of_a_run_has_the_runs_twin(tmp_path):
    from app.files import twin_pair

    run = tmp_path / "run"
    run.mkdir()
    (run / "config.json").write_text("{}")
    for name in ("model_stage1.ply", "model_final.ply", "model_edit_1.ply"):
        (run / name).write_bytes(b"ply")
    assert twin_pair(run / "model_final.ply") is None and twin_pair(None) is None
    first, second = (run / "fields" / f"field{k}" / "model.ply" for k in range(2))
    for path in (first, second):  # a run of two stage-1 fields: they are compared with each other
        path.parent.mkdir(parents=True)
        path.write_bytes(b"ply")
    for name in ("model_stage1.ply", "model_final.ply", "model_edit_1.ply"):
        assert twin_pair(run / name) == (first, second)
    (run / "model_stage1_twin.ply").write_bytes(b"ply")
    for name in ("model_stage1.ply", "model_final.ply", "model_edit_1.ply"):  # co_fields' twin first, as stage 2
        assert twin_pair(run / name) == (None, run / "model_stage1_twin.ply")
    assert twin_pair(run / "model_stage1_twin.ply") == (first, second)  # not its own twin
    (tmp_path / "bare.ply").write_bytes(b"ply")  # outside a run: <stem>_twin beside it
    assert twin_pair(tmp_path / "bare.ply") is None
    (tmp_path / "bare_twin.ply").write_bytes(b"ply")
    assert twin_pair(tmp_path / "bare.ply") == (None, tmp_path / "bare_twin.ply")


def test_without_a_twin_the_mode_is_greyed_out_and_says_how_to_get_one(make_viewer, tiny, tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "cfg"))
    d = _open(make_viewer, _run(tmp_path, tiny))
    v = d.viewer
    assert v.twin_pair() is None
    x, y = _radio(d, monkeypatch)
    for _ in range(30):  # rest on it: its tooltip says why and how
        d.move(x, y)
        if v.tooltip_shown:
            break
    assert v.tooltip_shown == f"model_stage1.ply has no twin field; a run trained with\n{HOW_TO_GET_A_TWIN} has one"
    assert HOW_TO_GET_A_TWIN == "fixer4d run ... --set training.fields=2"
    d.click(x, y)
    assert v.state.debug_mode == "color"  # disabled: nothing chosen
    # a session that left the mode on shows the colours, and the legend the way to a twin
    d.settle()
    colours = v.shown_image()
    v.state.debug_mode = "undetermined"
    d.settle()
    np.testing.assert_array_equal(v.shown_image(), colours)
    assert legend(v).note == v.tooltip_shown


def test_an_identical_twin_gives_an_all_zero_map(make_viewer, tiny, tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "cfg"))
    render_twin, calls = _counting(TwinRenders())
    d = _open(make_viewer, _run(tmp_path, tiny, twin=lambda g: g), render_twin)
    v = d.viewer
    assert v.twin_pair()[1].name == "model_stage1_twin.ply"
    d.click(*_radio(d, monkeypatch))
    assert v.state.debug_mode == "undetermined"
    d.settle()
    assert calls and set(calls) == {"model_stage1_twin.ply"}  # through the injected twin renderer
    assert not v.map_stale and v.undetermined_share == 0.0
    tex = v.splats._scalar_tex
    assert tex.size[0] > 1 and not np.frombuffer(tex.read(), np.float32).any()
    lg = legend(v)
    assert (lg.lo, lg.hi, lg.title) == (0.0, 1.0, UNDETERMINED_TITLE)
    assert lg.note == "0.0% of the view undetermined (map >= 0.5)"


def test_a_run_of_two_fields_maps_where_its_fields_disagree(make_viewer, tiny, tmp_path, monkeypatch):
    """Both fields are rendered through the injected twin renderer, whatever model is shown."""
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "cfg"))
    seen = []

    def render_twin(path, background, backend):
        seen.append(path.parent.name)
        return TwinRenders()(path, background, backend)

    d = _open(make_viewer, _run(tmp_path, tiny, fields=_half_recoloured), render_twin, snap=False)
    v = d.viewer
    v.state.debug_mode = "undetermined"
    d.settle()
    assert set(seen) == {"field0", "field1"}
    assert 0.2 < v.undetermined_share < 0.8


def _half_recoloured(g):
    """The twin field: the same Gaussians, those left of the scene's middle in other colours."""
    from dataclasses import replace

    left = g.means[:, 0] < np.median(g.means[:, 0])
    colors = g.colors.copy()
    colors[left] = -colors[left] + 1.5
    return replace(g, colors=colors)


def test_a_twin_that_differs_marks_where_with_its_legend(make_viewer, tiny, tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "cfg"))
    d = _open(make_viewer, _run(tmp_path, tiny, twin=_half_recoloured), snap=False)
    v = d.viewer
    v.state.debug_mode = "undetermined"
    d.settle()
    assert 0.2 < v.undetermined_share < 0.8
    assert legend(v).note == f"{100 * v.undetermined_share:.1f}% of the view undetermined (map >= 0.5)"
    x0, y0, x1, y1 = (int(round(c)) for c in v.window_rects["viewport"])
    save_shot(np.ascontiguousarray(v.screenshot(d.fbo)[y0:y1, x0:x1]), "viewer_viewport_undetermined", tmp_path)
    bx0, _, bx1, _ = v.item_rects["legend_box"]  # the box holds the title and the note whole
    assert max(imgui.calc_text_size(UNDETERMINED_TITLE).x, imgui.calc_text_size(legend(v).note).x) <= bx1 - bx0
    first = v.scalar_key
    v.adaptive.full_cost_ms = 1e6  # as on a slow GL: moving frames are reduced, not final
    v.state.view.rotate(20.0, 0.0, 400)
    d.frame()
    assert v.map_stale and "stale" in legend(v).note
    d.settle()
    assert not v.map_stale and v.scalar_key != first  # computed again for the resting view
