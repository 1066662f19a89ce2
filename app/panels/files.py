"""The File menu and its path dialog: open a run folder or a model file (.ply / .npz), switch
between the run's model versions, save the displayed model as a new version, export/import
trajectory presets and nerfstudio camera paths, write a screenshot. Paths are shown in full;
relative ones resolve under the run folder (or the viewer's session folder), never the
working directory."""
from __future__ import annotations

from imgui_bundle import imgui

from app.panels._layout import elide, error_text, tip

# Dialog actions: title, button label, whether the path must exist (read) or is written.
ACTIONS = {
    "open": ("Open a run folder, a model file (.ply / .npz), a scene or a folder of videos (trained live)",
             "open", True),
    "import_preset": ("Import trajectories from a fixer4d preset JSON", "import", True),
    "export_preset": ("Export the trajectories as a fixer4d preset JSON", "export", False),
    "import_camera_path": ("Import a nerfstudio camera_path JSON as a custom trajectory", "import", True),
    "export_camera_path": ("Export the selected trajectory as a nerfstudio camera_path JSON", "export", False),
    "save_model_as": ("Save the displayed model (.ply / .npz)", "save", False),
}
DEFAULT_NAMES = {"open": "", "import_preset": "viewer/trajectories.json", "export_preset": "viewer/trajectories.json",
                 "import_camera_path": "viewer/camera_path.json", "export_camera_path": "viewer/camera_path.json",
                 "save_model_as": "model_view.ply"}
MENU_LABELS = {"import_preset": "Import trajectory preset...", "export_preset": "Export trajectory preset...",
               "import_camera_path": "Import camera_path...", "export_camera_path": "Export camera_path..."}
POPUP = "File##dialog"
# Width of the dialog's path field (pixels): full paths of a few folders deep stay readable.
PATH_FIELD_WIDTH = 640


def _ui(viewer) -> dict:
    return viewer.__dict__.setdefault("_file_ui", {"action": None, "path": "", "open": False, "error": ""})


def ask(viewer, action: str, path: str | None = None) -> None:
    """Open the path dialog for ``action`` (prefilled with ``path`` or the default, in full)."""
    ui = _ui(viewer)
    ui["action"], ui["error"], ui["open"] = action, "", True
    if path is None:
        name = DEFAULT_NAMES[action]
        path = str(viewer.output_path(name)) if name else str(viewer.output_dir) + "/"
    ui["path"] = path


def draw_menu(viewer) -> None:
    """The File menu's items (inside the main menu bar)."""
    st, src = viewer.state, viewer.source
    opened = imgui.begin_menu("File")
    viewer.record_item("menu_file")
    if not opened:
        return
    if imgui.menu_item("Open run folder or model...", "Ctrl+O", False)[0]:
        ask(viewer, "open")
    viewer.record_item("menu_open")
    versions = viewer.model_versions()
    if imgui.begin_menu("Model version", bool(versions)):
        for p in versions:
            if imgui.menu_item(p.name, "", src.model_path == p)[0]:
                viewer.open_version(p)
            viewer.record_item(f"menu_version_{p.name}")
        imgui.end_menu()
    import app.panels.report as report

    report.draw_menu_item(viewer)
    imgui.separator()
    if imgui.menu_item("Save as new model version", "Ctrl+S", False, st.gaussians is not None)[0]:
        viewer.save_edited_model()
    viewer.record_item("menu_save_version")
    if imgui.menu_item("Save model as...", "", False, st.gaussians is not None)[0]:
        ask(viewer, "save_model_as")
    imgui.separator()
    for action, label in MENU_LABELS.items():
        if imgui.menu_item(label, "", False)[0]:
            ask(viewer, action)
        viewer.record_item(f"menu_{action}")
    imgui.separator()
    if imgui.menu_item("Quit", "Ctrl+Q", False)[0]:
        viewer.request_close()
    viewer.record_item("menu_quit")
    imgui.end_menu()


def draw_dialog(viewer) -> None:
    """The modal path dialog (a text field with the full path, the run's model versions as
    shortcuts for "open"); errors from the action show in the dialog and the notifications."""
    ui = _ui(viewer)
    if ui["open"]:
        imgui.open_popup(POPUP)
        ui["open"] = False
    if not imgui.begin_popup_modal(POPUP, None, imgui.WindowFlags_.always_auto_resize.value)[0]:
        return
    title, verb, _ = ACTIONS.get(ui["action"] or "open", ACTIONS["open"])
    imgui.text(title)
    imgui.set_next_item_width(PATH_FIELD_WIDTH)
    _, ui["path"] = imgui.input_text("##path", ui["path"])
    viewer.record_item("dialog_path")
    tip("a full path, or one relative to the folder below; for Open: a run folder, a model file, a scene "
        "folder or spec, a folder of videos (a capture), or 'demo'", viewer)
    imgui.text_disabled(elide(f"relative paths are under {viewer.output_dir}", PATH_FIELD_WIDTH))
    if ui["action"] == "open":
        from app.files import recent

        versions = [str(p) for p in viewer.model_versions()]
        lists = (("model versions of this run:", versions),
                 ("opened before in the viewer:", [r for r in recent(viewer.services.config_dir) if r not in versions]))
        for heading, items in lists:
            if items:
                imgui.text(heading)
            for text in items:
                if imgui.selectable(elide(text, PATH_FIELD_WIDTH) + f"##{heading}{text}", text == ui["path"])[0]:
                    ui["path"] = text
                tip(f"put {text} in the path field", viewer)
        if imgui.button("the built-in demo scene (trained live)"):
            ui["path"] = "demo"
        tip("the bundled synthetic demo scene, trained live in the viewer ('demo' always names it; a folder "
            "called demo is ./demo)", viewer)
    if ui["error"]:
        error_text(ui["error"])
    ok = imgui.button(verb)
    viewer.record_item("dialog_ok")
    tip(f"{verb} the path above", viewer)
    imgui.same_line()
    cancel = imgui.button("cancel")
    tip("close this dialog (Esc)", viewer)
    if cancel or imgui.is_key_pressed(imgui.Key.escape, False):
        imgui.close_current_popup()
    elif ok:
        try:
            done = run_action(viewer, ui["action"], ui["path"])
        except Exception as exc:  # stays open with the message; also in the notifications
            ui["error"] = f"{type(exc).__name__}: {exc}"
            viewer.report_error("file", exc)
        else:
            viewer.state.status = done
            viewer.notifications.info("file", done)
            imgui.close_current_popup()
    imgui.end_popup()


def run_action(viewer, action: str, text: str) -> str:
    """Do a dialog action with the typed path; returns the status line (full paths)."""
    from app import trajectories as traj
    from app.files import resolve_input
    from app.state import UNDO_HINT

    st = viewer.state
    train = [] if viewer.source.scene is None else viewer.source.scene.train_cameras
    if action == "open":
        return viewer.open_path(text)
    if action == "import_preset":
        path = resolve_input(text, viewer.output_dir)
        st.set_trajectories(traj.load_preset(path), f"import {path}", selected=0, destructive=True)
        return f"imported {len(st.trajectories)} trajectories from {path} in place of the list: {UNDO_HINT}"
    if action == "import_camera_path":
        path = resolve_input(text, viewer.output_dir)
        st.add_trajectory(traj.load_camera_path(path))
        return f"imported {path}"
    path = viewer.output_path(text)
    path.parent.mkdir(parents=True, exist_ok=True)
    if action == "export_preset":
        return f"wrote {traj.save_preset(path, st.trajectories, train)}"
    if action == "export_camera_path":
        k = st.selected_trajectory
        if not 0 <= k < len(st.trajectories):
            raise ValueError("select a trajectory to export")
        return f"wrote {traj.save_camera_path(path, st.trajectories[k], train, min(st.time, 0.999999), st.fps)}"
    if action == "save_model_as":
        # a run's models are the pipeline's results: a typed name must never replace one (or any file)
        if path.exists():
            raise ValueError(f"{path} exists: the viewer never replaces a file; type a new name, or use "
                             "File > Save as new model version")
        return f"wrote {viewer.save_model(path)}"
    raise ValueError(f"unknown file action {action!r}")
