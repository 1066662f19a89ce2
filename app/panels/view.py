"""View and edit: orbit/fly, snap to any train or held-out camera, frusta and paths on/off, the
background (black, white, the run's colour), selection tools (box, brush), delete/isolate the
selection, save as a new model version, undo/redo."""
from __future__ import annotations

import numpy as np
from imgui_bundle import imgui

from app.panels._layout import (button_width, combo_fit, leave_room_for_label, one_line, panel, same_line_if_fits,
                                tip, toggle_width)
from app.state import BACKGROUNDS

TOOLS = ("navigate", "box", "brush")


def draw(viewer) -> None:
    with panel(viewer, "view", "View & edit", 5, 30, 290, 330) as expanded:
        if not expanded:
            return
        _camera_section(viewer)
        imgui.separator()
        _selection_section(viewer)
        _edit_section(viewer)


def _camera_section(viewer) -> None:
    """Orbit/fly, reset view, snap to a scene camera, frusta and trajectories on/off."""
    st = viewer.state
    scene = viewer.source.scene
    imgui.text("camera")
    for mode in ("orbit", "fly"):
        same_line_if_fits(toggle_width(mode))
        if imgui.radio_button(mode, st.view.mode == mode):
            st.view.mode = mode
        tip("orbit: drag turns around the target; fly: drag looks around, W/A/S/D/Q/E move (mouse over "
            "the view)" if mode == "orbit" else "fly: drag looks around, W/A/S/D/Q/E move", viewer)
    same_line_if_fits(button_width("reset view"))
    reset = imgui.button("reset view")
    viewer.record_item("reset_view")
    tip("back to the first view of this scene", viewer)
    if reset:
        from app.camera_control import ViewCamera

        st.view = ViewCamera.from_dict(viewer.home_view.to_dict())
        st.previewing = False
    if scene is not None:
        _snap_combo(viewer, scene)
    _, st.show_frusta = imgui.checkbox("frusta", st.show_frusta)
    tip("the scene's cameras: train in green, held-out in orange", viewer)
    same_line_if_fits(toggle_width("trajectories"))
    _, st.show_trajectories = imgui.checkbox("trajectories", st.show_trajectories)
    tip("the novel-view trajectories' paths (the selected one in magenta)", viewer)
    _background_combo(viewer)


def _background_combo(viewer) -> None:
    """What the view shows where no Gaussian lies: black (holes stand out), white, or the colour
    the run trained over (offered where the source has one)."""
    st, run_rgb = viewer.state, viewer.source.background
    modes = [m for m in BACKGROUNDS if m != "run" or run_rgb is not None]
    names = ["run's colour" if m == "run" else m for m in modes]
    hint = "shown where no Gaussian lies: black makes holes stand out"
    if run_rgb is not None:
        hint += ("; the run's colour (RGB {}) shows the view as the run renders and restores it"
                 .format(", ".join(str(int(round(255 * x))) for x in run_rgb)))
    leave_room_for_label("background")
    changed, idx = combo_fit("background", modes.index(st.background_mode) if st.background_mode in modes else 0,
                             names, hint, viewer)
    viewer.record_item("background")
    if changed:
        st.choose_background(modes[idx], run_rgb)


def _snap_combo(viewer, scene) -> None:
    """The "snap to" list of the scene's cameras (the one the view is snapped to, if any, shown)."""
    st = viewer.state
    names = [f"{'train' if i in scene.train_ids else 'test'} camera {c.name or i}  ({c.width}x{c.height})"
             for i, c in enumerate(scene.cameras)]
    snapped = st.view.snapped
    current = next((i for i, c in enumerate(scene.cameras) if snapped is not None and c.name == snapped.name
                    and np.allclose(c.c2w, snapped.c2w)), -1)
    leave_room_for_label("snap to")
    changed, idx = combo_fit("snap to", current, names, "show exactly what a scene camera saw: its pose and "
                             "intrinsics (letterboxed)", viewer, none_text="(free)")
    if changed and idx >= 0:
        st.view.snap_to(scene.cameras[idx])
        st.previewing = False


def _selection_section(viewer) -> None:
    """The selection tools (navigate, box, brush), box-through and the selection count."""
    st = viewer.state
    imgui.text("select Gaussians (now)")
    tip("selection works on the Gaussians as they are at the current time", viewer)
    for k, tool in enumerate(TOOLS):
        if k:
            same_line_if_fits(toggle_width(tool))
        if imgui.radio_button(tool, viewer.tool == tool):
            viewer.tool = tool
        viewer.record_item(f"tool_{tool}")
        tip({"navigate": "mouse steers the camera", "box": "drag a box: select the Gaussians in it (Shift adds)",
             "brush": "drag: add the Gaussians under the brush"}[tool], viewer)
    same_line_if_fits(toggle_width("through"))
    _, viewer.select_through = imgui.checkbox("through", viewer.select_through)
    viewer.record_item("select_through")
    tip("off: the box takes only the front surface (what you see); on: everything in the box, hidden "
        "Gaussians behind it included", viewer)
    n_sel = 0 if st.selection is None else int(st.selection.sum())
    n = 0 if st.gaussians is None else st.gaussians.n
    imgui.text(f"{n_sel} of {n} selected")


def _edit_section(viewer) -> None:
    """Clear selection, delete, isolate, save as a new version, undo and redo."""
    st = viewer.state
    if imgui.button("clear selection"):
        st.set_selection(None)
    tip("select nothing", viewer)
    same_line_if_fits(button_width("delete"))
    delete = imgui.button("delete")
    viewer.record_item("delete")
    tip("remove the selected Gaussians (Ctrl+Z undoes)", viewer)
    if delete:
        st.delete_selected()
    same_line_if_fits(button_width("isolate"))
    isolate = imgui.button("isolate")
    viewer.record_item("isolate")
    tip("keep only the selected Gaussians (Ctrl+Z undoes)", viewer)
    if isolate:
        st.isolate_selected()
    if imgui.button("save as new version"):
        viewer.save_edited_model()
    tip("write RUN/model_edit_<k>.ply (Ctrl+S); the run reopens with it", viewer)
    same_line_if_fits(button_width("undo"))
    imgui.begin_disabled(not st.undo_stack)
    undo = imgui.button("undo")
    viewer.record_item("undo")
    tip(f"undo: {st.undo_stack[-1].label} (Ctrl+Z)" if st.undo_stack else "nothing to undo", viewer)
    if undo:
        st.undo()
    imgui.end_disabled()
    same_line_if_fits(button_width("redo"))
    imgui.begin_disabled(not st.redo_stack)
    redo = imgui.button("redo")
    tip(f"redo: {st.redo_stack[-1].label} (Ctrl+Y)" if st.redo_stack else "nothing to redo", viewer)
    if redo:
        st.redo()
    imgui.end_disabled()
    if st.undo_stack:  # the last edit, on a line of its own: a long label never pushes the buttons
        one_line(st.undo_stack[-1].label, viewer)
