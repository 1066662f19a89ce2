"""View and edit: orbit/fly, snap to any train or held-out camera, frusta and paths on/off,
selection tools (box, brush), delete/isolate the selection, save as a new model version,
undo/redo."""
from __future__ import annotations

from imgui_bundle import imgui

from app.panels._layout import panel

TOOLS = ("navigate", "box", "brush")


def draw(viewer) -> None:
    st = viewer.state
    scene = viewer.source.scene
    with panel(viewer, "view", "View & edit", 5, 30, 290, 330) as expanded:
        if not expanded:
            return
        imgui.text("camera")
        for mode in ("orbit", "fly"):
            if imgui.radio_button(mode, st.view.mode == mode):
                st.view.mode = mode
            imgui.same_line()
        imgui.new_line()
        if scene is not None:
            names = [f"{'train' if i in scene.train_ids else 'test '} {c.name or i}" for i, c in enumerate(scene.cameras)]
            current = next((i for i, c in enumerate(scene.cameras) if st.view.snapped is c), -1)
            changed, idx = imgui.combo("snap to", current, names)
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
