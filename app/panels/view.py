"""View and edit: orbit/fly, snap to any train or held-out camera, frusta and paths on/off,
selection tools (box, brush), delete/isolate the selection, save as a new model version,
undo/redo."""
from __future__ import annotations

import numpy as np
from imgui_bundle import imgui

from app.panels._layout import panel

TOOLS = ("navigate", "box", "brush")


def draw(viewer) -> None:
    st = viewer.state
    scene = viewer.source.scene
    with panel(viewer, "view", "View & edit", 5, 30, 290, 265) as expanded:
        if not expanded:
            return
        imgui.text("camera")
        imgui.same_line()
        for mode in ("orbit", "fly"):
            if imgui.radio_button(mode, st.view.mode == mode):
                st.view.mode = mode
            imgui.same_line()
        reset = imgui.button("reset view")
        viewer.record_item("reset_view")
        if reset:
            from app.camera_control import ViewCamera

            st.view = ViewCamera.from_dict(viewer.home_view.to_dict())
            st.previewing = False
        if scene is not None:
            names = [f"{'train' if i in scene.train_ids else 'test'} camera {c.name or i}  ({c.width}x{c.height})"
                     for i, c in enumerate(scene.cameras)]
            snapped = st.view.snapped
            current = next((i for i, c in enumerate(scene.cameras) if snapped is not None and c.name == snapped.name
                            and np.allclose(c.c2w, snapped.c2w)), -1)
            imgui.set_next_item_width(-60)
            changed, idx = combo_with_preview("snap to", current, names, "(free camera)")
            if changed and idx >= 0:
                st.view.snap_to(scene.cameras[idx])
                st.previewing = False
        _, st.show_frusta = imgui.checkbox("frusta", st.show_frusta)
        imgui.same_line()
        _, st.show_trajectories = imgui.checkbox("trajectories", st.show_trajectories)
        imgui.separator()
        imgui.text("select Gaussians (at the current time)")
        for tool in TOOLS:
            if imgui.radio_button(tool, viewer.tool == tool):
                viewer.tool = tool
            viewer.record_item(f"tool_{tool}")
            imgui.same_line()
        imgui.new_line()
        n_sel = 0 if st.selection is None else int(st.selection.sum())
        n = 0 if st.gaussians is None else st.gaussians.n
        imgui.text(f"{n_sel} of {n} selected")
        if imgui.button("clear selection"):
            st.set_selection(None)
        imgui.same_line()
        delete = imgui.button("delete")
        viewer.record_item("delete")
        if delete:
            st.delete_selected()
        imgui.same_line()
        if imgui.button("isolate"):
            st.isolate_selected()
        if imgui.button("save as new model version"):
            viewer.save_edited_model()
        imgui.begin_disabled(not st.undo_stack)
        undo = imgui.button("undo")
        viewer.record_item("undo")
        if undo:
            st.undo()
        imgui.end_disabled()
        imgui.same_line()
        imgui.begin_disabled(not st.redo_stack)
        if imgui.button("redo"):
            st.redo()
        imgui.end_disabled()
        if st.undo_stack:
            imgui.same_line()
            imgui.text_disabled(st.undo_stack[-1].label)


def combo_with_preview(label: str, current: int, names: list[str], none_text: str) -> tuple[bool, int]:
    """A combo showing ``none_text`` when nothing (-1) is chosen; returns (changed, index)."""
    changed, idx = False, current
    if imgui.begin_combo(label, names[current] if 0 <= current < len(names) else none_text):
        for i, name in enumerate(names):
            if imgui.selectable(name, i == current)[0]:
                changed, idx = True, i
        imgui.end_combo()
    return changed, idx
