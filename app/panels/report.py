"""The run's report in the viewer: "File > Run report" opens a window with the run's held-out
rows (RUN/report.json, written by `fixer4d run`), the stage-2 self-check's decision with its
fold figures, and which model file is the final one, so a user who opens a run sees what it
measured without leaving the viewer."""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from imgui_bundle import imgui

from app.panels._layout import error_text, panel, tip

# The report's columns shown here: (row key, header, format).
COLUMNS = (("psnr", "PSNR", "{:.2f}"), ("psnr_unobserved", "unobserved", "{:.2f}"),
           ("dssim1", "DSSIM1", "{:.4f}"), ("lpips", "LPIPS", "{:.4f}"), ("seconds", "time (s)", "{:.1f}"))

# Longest cell text shown whole (a number or "n/a"; a failed row's reason is longer).
CELL_CHARS = 12


def read_report(run_dir: str | Path | None) -> dict[str, Any] | None:
    """What the window shows of RUN/report.json: {"scene", "rows": [(method, {header: text})],
    "self_check": line or None, "held_out": bool}; None without a report. A report that cannot be
    read raises ValueError naming the file."""
    if run_dir is None:
        return None
    path = Path(run_dir) / "report.json"
    if not path.is_file():
        return None
    try:
        report = json.loads(path.read_text())
        rows = report["rows"]
        if not (isinstance(rows, list) and all(isinstance(r, dict) for r in rows)):
            raise TypeError("its rows are not a list of records")
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise ValueError(f"{path}: not a fixer4d report ({exc})") from exc
    from fixer4d.pipeline.report import self_check_line

    shown = []
    for row in rows:
        status = str(row.get("status", "ok"))
        if status == "ok":
            cells = {header: fmt.format(row[key]) if isinstance(row.get(key), (int, float)) else "n/a"
                     for key, header, fmt in COLUMNS}
        else:  # a row that failed says why in its first column (the window shows it on hover)
            cells = {header: (status if i == 0 else "") for i, (_, header, _) in enumerate(COLUMNS)}
        shown.append((str(row.get("method", "?")), cells))
    check = report.get("self_check")
    try:
        line = self_check_line(check).replace("**", "") if isinstance(check, dict) and check else None
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"{path}: not a fixer4d report (its self-check record: {exc!r})") from exc
    return {"scene": str(report.get("scene", "")), "rows": shown, "self_check": line,
            "held_out": not any(r.get("held_out") is False for r in rows)}


def _cached(viewer) -> dict[str, Any] | None:
    """``read_report`` of the opened run, read again only when report.json changes (a run still
    going rewrites it after each row)."""
    run = viewer.source.run_dir
    path = None if run is None else Path(run) / "report.json"
    stamp = (str(path), path.stat().st_mtime_ns) if path is not None and path.is_file() else None
    memo = viewer.__dict__.setdefault("_report_ui", {"stamp": None, "shown": None})
    if stamp != memo["stamp"]:
        memo["shown"], memo["stamp"] = read_report(run), stamp
    return memo["shown"]


def draw_menu_item(viewer) -> None:
    """File > Run report (enabled when the opened run has a report)."""
    has = viewer.source.run_dir is not None and (Path(viewer.source.run_dir) / "report.json").is_file()
    if imgui.menu_item("Run report", "", viewer.show_report, has)[0]:
        viewer.show_report = not viewer.show_report
    viewer.record_item("menu_report")


def draw(viewer) -> None:
    if not viewer.show_report:
        return
    with panel(viewer, "report", "Run report", 300, 120, 820, 360, front=True) as expanded:
        if not expanded:
            return
        try:
            shown = _cached(viewer)
        except ValueError as exc:
            error_text(str(exc))
            shown = None
        if shown is None:
            imgui.text_disabled("this run has no report yet (fixer4d run writes RUN/report.json)")
        else:
            imgui.text_wrapped(shown["scene"])
            if not shown["held_out"]:
                imgui.text_wrapped("No held-out camera: the rows show the fit to the train views.")
            # columns as wide as their longest text: method names are long, numbers short
            flags = (imgui.TableFlags_.row_bg.value | imgui.TableFlags_.borders_inner_v.value
                     | imgui.TableFlags_.sizing_fixed_fit.value)
            if imgui.begin_table("report_rows", 1 + len(COLUMNS), flags):
                imgui.table_setup_column("method")
                for _, header, _ in COLUMNS:
                    imgui.table_setup_column(header)
                imgui.table_headers_row()
                for method, cells in shown["rows"]:
                    imgui.table_next_row()
                    imgui.table_next_column()
                    imgui.text(method)
                    for _, header, _ in COLUMNS:
                        imgui.table_next_column()
                        text = cells[header]
                        if len(text) > CELL_CHARS:  # a failure's reason: its first word, the rest on hover
                            imgui.text_disabled(text.split(":")[0][:CELL_CHARS])
                            tip(text)
                        else:
                            imgui.text(text)
                imgui.end_table()
            if shown["self_check"]:
                imgui.text_wrapped(shown["self_check"])
        close = imgui.button("close")
        tip("hide this window (File > Run report shows it again)", viewer)
        if close:
            viewer.show_report = False
