"""Every text fits its column at the window sizes the viewer is used at: 1024x640 (a small
laptop) and 1440x900 (the default). Each label, button, status text and combo choice the panels
draw (menu bar and windows, all with their fullest content) is compared with the width its
column left it; screenshots of both sizes go to the docs."""
from __future__ import annotations

import itertools

import numpy as np
import pytest
from imgui_bundle import imgui

from app.panels._layout import overlaps
from app.state import UNDO_HINT
from doc_shots import save_shot
from fixer4d.scene import load_scene
from ui_walk import Recorder, busy_viewer
from viewer_helpers import DEFAULT_WINDOW, gl_ctx, make_viewer  # noqa: F401 (fixtures)

pytestmark = pytest.mark.gl
DOCKED = ("viewport", "view", "timeline", "trajectories", "restore", "compare", "training", "debug")


@pytest.fixture(scope="module")
def tiny():
    return load_scene("tiny")


@pytest.mark.parametrize("size", [(1024, 640), DEFAULT_WINDOW])
def test_no_text_is_cut(make_viewer, tiny, tmp_path, monkeypatch, size):
    d = busy_viewer(make_viewer, tiny, tmp_path, size)
    v = d.viewer
    v.state.status = f"delete trajectory 0-15_arc1: {UNDO_HINT}"  # a destructive edit's notice
    rec = Recorder(monkeypatch)
    d.frame()
    x0, _, x1, _ = v.item_rects["status_line"]
    assert x1 - x0 >= imgui.calc_text_size(v.state.status).x - 1.0  # shown whole, live training's line beside it
    assert {i.window for i in rec.items} >= {"View & edit", "Trajectories", "Restore", "Compare", "Training",
                                             "Debug", "Timeline", "Notifications", "Mouse and keys", "Run report",
                                             "##MainMenuBar"}
    assert len(rec.items) > 100
    cut = [why for item in rec.items if (why := item.cut()) is not None]
    assert not cut, "\n".join(cut)
    rects = {k: r for k, r in v.window_rects.items() if k in DOCKED}
    for (a, ra), (b, rb) in itertools.combinations(rects.items(), 2):
        assert not overlaps(ra, rb), (a, ra, b, rb)
    for name, (x0, y0, x1, y1) in v.window_rects.items():
        assert 0 <= x0 and 0 <= y0 and x1 <= size[0] + 1 and y1 <= size[1] + 1, (name, v.window_rects[name])
    # the File > Open dialog (full paths, the runs opened before) fits the window too
    from app.files import remember_recent
    from app.panels import files

    remember_recent(v.services.config_dir, str(tmp_path / ("a_folder_with_a_long_name_" * 6) / "run"))
    files.ask(v, "open")
    d.frame(2)
    rec.clear()
    d.frame()
    dialog = [i for i in rec.items if i.window == "File"]
    assert len(dialog) >= 5 and not [why for i in dialog if (why := i.cut()) is not None]
    assert all(0 <= i.rect[0] and i.rect[2] <= size[0] for i in dialog)
    d.press("escape")  # closes it
    # the picture: the holes overlay with its numbers (the Gaussian colour modes greyed out)
    from app.legends import legend

    v.show_help = v.show_report = v.show_notifications = False
    v.state.debug_mode = "holes"
    d.frame(3)
    assert [t for _, t in legend(v).ticks()] == ["0", "0.5", "1"]
    shot = v.screenshot(d.fbo)
    save_shot(shot, f"viewer_layout_{size[0]}x{size[1]}", tmp_path)
    if size == DEFAULT_WINDOW:  # each panel on its own, for the docs' panel table
        for name in DOCKED[1:]:
            x0, y0, x1, y1 = (int(round(c)) for c in v.window_rects[name])
            save_shot(np.ascontiguousarray(shot[y0:y1, x0:x1]), f"viewer_{name}", tmp_path)
