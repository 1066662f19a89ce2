"""Trajectory editor: the 6 pairs and the diagonal arcs, select, tune A / frame count /
direction, preview the render at any alpha, custom trajectories from keyframes (current view ->
key), delete, export/import presets (fixer4d JSON) and nerfstudio camera paths. Every change is
one undoable edit (sliders commit when released)."""
from __future__ import annotations

from imgui_bundle import imgui

from app import trajectories as traj
from app.panels._layout import (button_width, elide, error_text_line, leave_room_for_label, one_line, panel,
                                same_line_if_fits, tip)
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
    with panel(viewer, "trajectories", "Trajectories", 5, 365, 290, 530) as expanded:
        if not expanded:
            return
        if scene is not None:
            clicked = imgui.button("add the 6 pairs + arcs")
            viewer.record_item("add_default_trajectories")
            tip("the 6 camera pairs' paths (A = 0) and the arcs on the diagonal pairs, named by scene camera ids",
                viewer)
            if clicked:
                # only those not in the list yet (by name): a second click does not duplicate them
                have = {spec.name for spec in st.trajectories}
                new = [spec for spec in traj.default_specs(scene.train_cameras, max(2, scene.num_frames),
                                                            camera_ids=scene.train_ids)
                       if spec.name not in have]
                if new:
                    st.set_trajectories(st.trajectories + new, "add default trajectories",
                                        selected=len(st.trajectories))
                else:
                    st.status = "the pairs and arcs are in the list already"
        if scene is not None:
            same_line_if_fits(button_width("new from view"))
        new_view = imgui.button("new from view")
        tip("a custom trajectory whose first keyframe is the current view", viewer)
        if new_view:
            cam = viewer.render_camera or st.view.camera(640, 480)
            st.add_trajectory(TrajectorySpec(name=f"custom{len(st.trajectories)}", keyframes=(cam.to_dict(),)))
        imgui.begin_child("list", imgui.ImVec2(0, 110), imgui.ChildFlags_.borders.value)
        for k, spec in enumerate(st.trajectories):
            shape = f"A={spec.amplitude:.2f}" if spec.pair is not None else f"custom, {len(spec.keyframes)} keys"
            text = f"{spec.name}  {shape}  {spec.n_frames} frames{'  reversed' if spec.reverse else ''}"
            shown = elide(text, imgui.get_content_region_avail().x)
            if imgui.selectable(f"{shown}##{k}", k == st.selected_trajectory)[0]:
                st.selected_trajectory = k
            tip(("" if shown == text else text + "\n") + "select it: tune it below, preview it, render a video, "
                "queue restorations (Restore panel)", viewer)
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
    import app.panels.files as files

    imgui.text("preset (fixer4d JSON)" if field == "preset" else "camera_path (nerfstudio)")
    imgui.set_next_item_width(-1)
    _, ui[field] = imgui.input_text(f"##{field}", ui[field])
    tip("a path relative to the run folder (or the session folder), or a full path" if field == "preset" else
        "a nerfstudio camera_path JSON: export writes the selected trajectory, import adds it as a custom one",
        viewer)
    # the full path on one line (elided, whole on hover): a long one must not push the buttons down
    one_line(str(viewer.output_path(ui[field])) if ui[field].strip() else "(no file name)", viewer)
    export = imgui.button(f"export##{field}")
    viewer.record_item(f"export_{field}")
    tip("write the trajectories (all of them) to this file" if field == "preset" else
        "write the selected trajectory as a nerfstudio camera path to this file", viewer)
    imgui.same_line()
    do_import = imgui.button(f"import##{field}")
    viewer.record_item(f"import_{field}")
    tip("replace the trajectories by the file's (one undoable edit)" if field == "preset" else
        "add the file's camera path as a custom trajectory", viewer)
    if export:
        viewer.state.status = files.run_action(viewer, f"export_{field}", ui[field])
    if do_import:
        viewer.state.status = files.run_action(viewer, f"import_{field}", ui[field])


def _selected(viewer, k: int, pending: dict) -> None:
    """The selected trajectory's controls. Every row keeps its place whatever a job does: the
    video's progress, result or error has a one-line slot of its own under "render video"."""
    st = viewer.state
    spec = st.trajectories[k]
    if spec.pair is not None:
        ids = viewer.source.scene.train_ids if viewer.source.scene is not None else list(range(max(spec.pair) + 1))
        imgui.text(f"cameras {ids[spec.pair[0]]}-{ids[spec.pair[1]]}" +
                   (f", arc {spec.arc_index}" if spec.arc_index is not None else ""))
        tip("the scene's camera ids of the pair (as in the restore panel's clip names)", viewer)
        value = pending.get(("A", k), spec.amplitude)
        leave_room_for_label("A")
        changed, value = imgui.slider_float("A", value, *AMPLITUDE_RANGE)
        tip("arc amplitude A, in units of the rig radius: 0 is the straight path between the pair", viewer)
        if changed:
            pending[("A", k)] = value
        if imgui.is_item_deactivated_after_edit():
            st.update_trajectory(k, f"A of {spec.name} = {value:.3f}", amplitude=float(pending.pop(("A", k), value)))
    else:
        imgui.text(f"custom: {len(spec.keyframes)} keyframes")
        if imgui.button("add keyframe"):
            st.add_keyframe(k, viewer.render_camera or st.view.camera(640, 480))
        tip("append the 3D view's current camera as the last keyframe (Ctrl+Z undoes)", viewer)
    frames = pending.get(("F", k), spec.n_frames)
    leave_room_for_label("frames")
    changed, frames = imgui.slider_int("frames", frames, *FRAMES_RANGE)
    tip("frames along the trajectory (the clip length of its restorations and videos)", viewer)
    if changed:
        pending[("F", k)] = frames
    if imgui.is_item_deactivated_after_edit():
        st.update_trajectory(k, f"frames of {spec.name} = {frames}", n_frames=int(pending.pop(("F", k), frames)))
    changed, rev = imgui.checkbox("reverse", spec.reverse)
    tip("run the trajectory from its last camera to its first", viewer)
    if changed:
        st.update_trajectory(k, f"reverse {spec.name}", reverse=rev)
    imgui.same_line()
    changed, vis = imgui.checkbox("visible", spec.visible)
    tip("draw this trajectory's path in the 3D view", viewer)
    if changed:
        st.update_trajectory(k, f"{'show' if vis else 'hide'} {spec.name}", visible=vis)
    _, st.previewing = imgui.checkbox("preview", st.previewing)
    tip("show the 3D view from the trajectory's camera at alpha (0 = first camera, 1 = last)", viewer)
    imgui.same_line()
    imgui.set_next_item_width(-1)
    _, st.preview_alpha = imgui.slider_float("##alpha", st.preview_alpha, 0.0, 1.0, "alpha %.3f")
    tip("where along the trajectory the preview camera is (0 = first camera, 1 = last)", viewer)
    video_row(viewer, k)
    delete = imgui.button("delete trajectory")
    viewer.record_item("delete_trajectory")
    tip("remove the selected trajectory from the list (Ctrl+Z brings it back)", viewer)
    if delete:
        st.delete_trajectory(k)


def video_row(viewer, k: int) -> None:
    """"Render video" (the selected trajectory from the current frame, as a background job) on a
    row of its own, and one line under it that holds the job's progress and cancel, its result
    (the path, elided, with "open video") or its error: the rows below never move."""
    from app.video_job import VideoJob, trajectory_times

    st = viewer.state
    ui = viewer.__dict__.setdefault("_video_ui", {"job": None})
    job = ui["job"]
    running = job is not None and job.running
    imgui.begin_disabled(running)
    start = imgui.button("render video")
    imgui.end_disabled()
    viewer.record_item("render_video")
    tip("render the selected trajectory from the current frame to RUN/viewer/videos/<name>.mp4 in the "
        "background (torch renders of the shown model, edits included)", viewer)
    if start and not running:
        spec = st.trajectories[k]
        cams = viewer.trajectory_cameras(spec)
        out = viewer.output_path(f"viewer/videos/{spec.name}_f{st.frame:04d}.mp4")
        out.parent.mkdir(parents=True, exist_ok=True)
        job = ui["job"] = VideoJob(viewer.services.render_video, viewer.gaussians_render_fn(), cams,
                                   trajectory_times(st.frame, len(cams), st.num_frames), out, st.fps)
    video_status_line(viewer, ui, job)


def video_status_line(viewer, ui: dict, job) -> None:
    """Exactly one frame-high line: the running job's progress bar and cancel, the finished
    video's path and "open video", its error or "cancelled", or nothing yet."""
    y = imgui.get_cursor_pos_y()
    if job is None:
        imgui.text_disabled("no video rendered yet")
    elif job.running:
        cancel_w = button_width("cancel") + imgui.get_style().item_spacing.x
        imgui.progress_bar(job.progress, imgui.ImVec2(-cancel_w, 0), f"video {100 * job.progress:.0f}%")
        imgui.same_line()
        if imgui.small_button("cancel##video"):
            job.cancel()
        viewer.record_item("video_cancel")
        tip("stop rendering the video (the frames written so far are discarded)", viewer)
    elif job.error:
        if ui.get("reported") is not job:
            ui["reported"] = job
            viewer.report_error("video", job.error)
        error_text_line(f"video failed: {job.error}", viewer)
    elif job.cancelled:
        imgui.text_disabled("video cancelled")
    elif job.result is not None:
        opened = imgui.small_button("open video")
        viewer.record_item("video_open")
        tip("open the video with the desktop's default player (without one: its path is copied)", viewer)
        imgui.same_line()
        one_line(str(job.result), viewer)
        if opened:
            from app.desktop import open_with_desktop

            viewer.state.status = open_with_desktop(job.result, imgui.set_clipboard_text, "video")
            viewer.notifications.info("video", viewer.state.status)
    # the slot is one frame high whatever it held
    imgui.set_cursor_pos_y(y + imgui.get_frame_height_with_spacing())
