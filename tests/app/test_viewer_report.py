"""File > Run report: the run's held-out rows and the self-check's decision in the viewer."""
from __future__ import annotations

import json

import pytest

from app.panels.report import COLUMNS, read_report
from app.sources import initial_state
from app.viewer import ViewerSource
from doc_shots import save_shot
from fixer4d.scene import load_scene
from viewer_helpers import gl_ctx, make_viewer, scene_gaussians  # noqa: F401 (fixtures)

CHECK = {"decision": "skip", "held_back_camera": 15, "fold_cameras": [0, 3, 12], "scale": 0.5,
         "psnr": {"skip": 19.51, "continue": 19.57, "refine": 19.58}, "seconds": {"init": 2.0, "stage1": 60.0},
         "settings": {"tie_db": 0.1}}


def _report(run_dir, rows, check=CHECK):
    run_dir.mkdir(parents=True, exist_ok=True)
    (run_dir / "report.json").write_text(json.dumps({"rows": rows, "scene": "tiny: 8 cameras", "self_check": check}))


ROWS = [{"method": "STGS w/ MVS", "status": "ok", "psnr": 25.0183, "psnr_unobserved": 18.5, "dssim1": 0.0738,
         "lpips": None, "seconds": 101.4},
        {"method": "STGS w/ COLMAP", "status": "failed: no points"},
        {"method": "Full", "status": "ok", "psnr": 25.0183, "psnr_unobserved": 18.5, "dssim1": 0.0738,
         "lpips": 0.07, "seconds": 218.6}]


def test_read_report_rows_and_decision(tmp_path):
    assert read_report(None) is None and read_report(tmp_path) is None  # no run, no report yet
    _report(tmp_path, ROWS)
    shown = read_report(tmp_path)
    assert [m for m, _ in shown["rows"]] == ["STGS w/ MVS", "STGS w/ COLMAP", "Full"]
    mvs = dict(shown["rows"][0][1])
    assert mvs["PSNR"] == "25.02" and mvs["unobserved"] == "18.50" and mvs["LPIPS"] == "n/a"
    assert set(mvs) == {header for _, header, _ in COLUMNS}
    assert dict(shown["rows"][1][1])["PSNR"] == "failed: no points" and dict(shown["rows"][1][1])["LPIPS"] == ""
    assert "**" not in shown["self_check"] and "skip" in shown["self_check"] and "more than 0.1 dB" in shown["self_check"]
    assert shown["held_out"]
    for bad in ("{not json", "[]", '{"rows": 3}', '{"rows": [1, 2]}', '{"rows": [], "self_check": {"psnr": {"skip": 1}}}'):
        (tmp_path / "report.json").write_text(bad)
        with pytest.raises(ValueError, match="not a fixer4d report"):
            read_report(tmp_path)


@pytest.mark.gl
def test_the_report_window_opens_from_the_file_menu(make_viewer, tmp_path):
    tiny = load_scene("tiny")
    run = tmp_path / "run"
    _report(run, ROWS)
    src = ViewerSource(scene=tiny, label="tiny", run_dir=run)
    d = make_viewer(initial_state(src, scene_gaussians(tiny, stride=8)), src)
    v = d.viewer
    d.click_item("menu_file")
    d.click_item("menu_report")
    d.settle()
    assert v.show_report and "report" in v.window_rects and not v.panel_errors
    save_shot(v.screenshot(d.fbo), "viewer_report", tmp_path)
    # a run still going rewrites its report: the window follows
    _report(run, ROWS[:1], check=None)
    d.frame(2)
    assert [m for m, _ in v.__dict__["_report_ui"]["shown"]["rows"]] == ["STGS w/ MVS"]
    # without a report the menu item is disabled
    v.show_report = False
    (run / "report.json").unlink()
    d.click_item("menu_file")
    d.click_item("menu_report")
    d.frame()
    assert not v.show_report
