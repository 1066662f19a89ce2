"""Trajectory editor: the 6 pairs and the diagonal arcs, select, tune A / frame count /
direction, preview the render at any alpha, custom trajectories from keyframes (current view ->
key), delete, export/import presets (fixer4d JSON) and nerfstudio camera paths. Every change is
one undoable edit (sliders commit when released)."""
from __future__ import annotations

from imgui_bundle import imgui

from app import trajectories as traj
from app.panels._layout import panel
from app.state import TrajectorySpec

# Slider ranges: A in units of the rig radius, frame counts per clip.
AMPLITUDE_RANGE = (0.0, 2.0)
FRAMES_RANGE = (2, 120)


def draw(viewer) -> None:
    st = viewer.state
    scene = viewer.source.scene
    ui = viewer.__dict__.setdefault("_traj_ui", {"preset": "viewer/trajectories.json",
                                                 "camera_path": "viewer/camera_path.json",
                                                 "pending": {}})
    with panel(viewer, "trajectories", "Trajectories", 5, 300, 290, 595) as expanded:
        if not expanded:
            return
        if scene is not None:
            clicked = imgui.button("add the 6 pairs + arcs")
            viewer.record_item("add_default_trajectories")
            if clicked:
                # only those not in the list yet (by name): a second click does not duplicate them
                have = {spec.name for spec in st.trajectories}
                new = [spec for spec in traj.default_specs(scene.train_cameras, max(2, scene.num_frames))
                       if spec.name not in have]
                if new:
                    st.set_trajectories(st.trajectories + new, "add default trajectories",
                                        selected=len(st.trajectories))
                else:
                    st.status = "the pairs and arcs are in the list already"
        imgui.same_line()
        if imgui.button("new from view"):
            cam = viewer.render_camera or st.view.camera(640, 480)
            st.add_trajectory(TrajectorySpec(name=f"custom{len(st.trajectories)}", keyframes=(cam.to_dict(),)))
        imgui.begin_child("list", imgui.ImVec2(0, 110), imgui.ChildFlags_.borders.value)
        for k, spec in enumerate(st.trajectories):
            shape = f"A={spec.amplitude:.2f}" if spec.pair is not None else f"custom, {len(spec.keyframes)} keys"
            label = f"{spec.name}  {shape}  {spec.n_frames} frames{'  reversed' if spec.reverse else ''}##{k}"
            if imgui.selectable(label, k == st.selected_trajectory)[0]:
                st.selected_trajectory = k
        imgui.end_child()
        k = st.selected_trajectory
        if 0 <= k < len(st.trajectories):
            _selected(viewer, k, ui["pending"])
        imgui.separator()
        for field in ("preset", "camera_path"):
            file_row(viewer, ui, field)


def file_row(viewer, ui: dict, field: str) -> None:
    """A path field (relative paths under the run/session folder, the full path shown below)
    with export and import buttons; errors go to the panel's guard."""
    from app.panels import files

    imgui.text("preset file (fixer4d JSON)" if field == "preset" else "camera_path file (nerfstudio JSON)")
    imgui.set_next_item_width(-1)
    _, ui[field] = imgui.input_text(f"##{field}", ui[field])
    if ui[field].strip():
        imgui.push_text_wrap_pos(0.0)
        imgui.text_disabled(str(viewer.output_path(ui[field])))
        imgui.pop_text_wrap_pos()
    export = imgui.button(f"export##{field}")
    viewer.record_item(f"export_{field}")
    imgui.same_line()
    do_import = imgui.button(f"import##{field}")
    viewer.record_item(f"import_{field}")
    if export:
        viewer.state.status = files.run_action(viewer, f"export_{field}", ui[field])
    if do_import:
        viewer.state.status = files.run_action(viewer, f"import_{field}", ui[field])


def _selected(viewer, k: int, pending: dict) -> None:
    st = viewer.state
    spec = st.trajectories[k]
    if spec.pair is not None:
        imgui.text(f"pair {spec.pair[0]} - {spec.pair[1]}" + (f", arc {spec.arc_index}" if spec.arc_index is not None else ""))
        value = pending.get(("A", k), spec.amplitude)
        changed, value = imgui.slider_float("A", value, *AMPLITUDE_RANGE)
        if changed:
            pending[("A", k)] = value
        if imgui.is_item_deactivated_after_edit():
            st.update_trajectory(k, f"A of {spec.name} = {value:.3f}", amplitude=float(pending.pop(("A", k), value)))
    else:
        imgui.text(f"custom: {len(spec.keyframes)} keyframes")
        if imgui.button("add keyframe (current view)"):
            st.add_keyframe(k, viewer.render_camera or st.view.camera(640, 480))
    frames = pending.get(("F", k), spec.n_frames)
    changed, frames = imgui.slider_int("frames", frames, *FRAMES_RANGE)
    if changed:
        pending[("F", k)] = frames
    if imgui.is_item_deactivated_after_edit():
        st.update_trajectory(k, f"frames of {spec.name} = {frames}", n_frames=int(pending.pop(("F", k), frames)))
    changed, rev = imgui.checkbox("reverse", spec.reverse)
    if changed:
        st.update_trajectory(k, f"reverse {spec.name}", reverse=rev)
    imgui.same_line()
    changed, vis = imgui.checkbox("visible", spec.visible)
    if changed:
        st.update_trajectory(k, f"{'show' if vis else 'hide'} {spec.name}", visible=vis)
    _, st.previewing = imgui.checkbox("preview", st.previewing)
    imgui.same_line()
    imgui.set_next_item_width(-1)
    _, st.preview_alpha = imgui.slider_float("##alpha", st.preview_alpha, 0.0, 1.0, "alpha %.3f")
    if imgui.button("delete trajectory"):
        st.delete_trajectory(k)
