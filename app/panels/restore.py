"""Restoration jobs: queue the selected trajectory x timestamps to the background worker;
progress, cancel and failures shown; finished clips land in the cache (the compare panel
reads them)."""
from __future__ import annotations

import re

from imgui_bundle import imgui

from app.panels._layout import combo_fit, elide, leave_room_for_label, one_line, panel, tip


def draw(viewer) -> None:
    st = viewer.state
    src = viewer.source
    ui = viewer.__dict__.setdefault("_restore_ui", {"every": 0})
    with panel(viewer, "restore", "Restore", 1105, 365, 330, 230) as expanded:
        if not expanded:
            return
        if src.restore is None or src.scene is None:
            imgui.text_wrapped("Restoration needs a scene and a restorer (open a run folder or a scene).")
        else:
            restorer_choice(viewer, src)
            k = st.selected_trajectory
            name = st.trajectories[k].name if 0 <= k < len(st.trajectories) else "(select a trajectory)"
            one_line(f"trajectory: {name}", viewer, disabled=False,
                     hint="the trajectory selected in the Trajectories panel; pair names are the scene's camera ids, "
                          "as in the clip names below")
            imgui.text_wrapped("frames: every n-th (0 = the current one)")
            leave_room_for_label("n", at_most=120)
            _, ui["every"] = imgui.input_int("n", ui["every"])
            tip("0: restore the current frame only; n > 0: frames 0, n, 2n, ... of the clip", viewer)
            ui["every"] = max(0, ui["every"])
            queue = 0 <= k < len(st.trajectories) and imgui.button("queue")
            viewer.record_item("queue")
            tip("render the trajectory at those frames and restore them in the background; finished clips go "
                "to the cache (Compare shows them)", viewer)
            if queue:
                frames = [st.frame] if ui["every"] == 0 else list(range(0, st.num_frames, ui["every"]))
                for f in frames:
                    queue_restore(viewer, k, f)
            imgui.separator()
            for n, item in enumerate(reversed(src.restore.items)):
                restore_item(viewer, n, item)


def restore_item(viewer, n: int, item) -> None:
    """One queued restoration in exactly two lines, whatever its state: [cancel] and the clip
    name, then a progress bar that says the status (or the error, whole on hover), so a job that
    finishes or fails never moves the rows under it."""
    imgui.push_id(str(n))
    active = item.status in ("rendering", "queued", "running", "submitted")
    imgui.begin_disabled(not active)
    if imgui.small_button("cancel"):
        item.cancel()
    imgui.end_disabled()
    viewer.record_item(f"restore_cancel_{n}")
    tip(f"stop restoring {item.key} (a clip being restored is not written to the cache)" if active else
        f"{item.key} is {item.status}", viewer)
    imgui.same_line()
    one_line(item.key, viewer, disabled=False)
    err = item.error or (getattr(item.job, "error", None) if item.job is not None else None)
    text = f"{item.status}: {err}" if err else item.status
    shown = elide(text, max(imgui.get_content_region_avail().x - 8.0, 8.0))
    if err:
        imgui.push_style_color(imgui.Col_.plot_histogram.value, imgui.ImVec4(0.8, 0.25, 0.2, 1.0))
    imgui.progress_bar(item.progress, imgui.ImVec2(-1, 0), shown)
    if err:
        imgui.pop_style_color()
    if shown != text:
        tip(text, viewer)
    imgui.pop_id()


def queue_restore(viewer, k: int, frame: int):
    """Queue trajectory ``k`` of the state at ``frame``; returns the ``QueuedRestore``."""
    from app.session import restore_request
    from app.trajectories import spec_meta

    st, src = viewer.state, viewer.source
    spec = st.trajectories[k]
    cams = viewer.trajectory_cameras(spec)
    scene = src.scene
    if spec.pair is not None:
        ref_ids = (scene.train_ids[spec.pair[0]], scene.train_ids[spec.pair[1]])
        key = viewer_clip_key(src.cache.key(frame, ref_ids[0], ref_ids[1], spec.arc_index), spec)
    else:
        ref_ids = tuple(_nearest_train(scene, c) for c in (cams[0], cams[-1]))
        key = viewer_clip_key(f"t{frame:04d}_" + re.sub(r"[^A-Za-z0-9_-]+", "_", spec.name), spec)
    if spec.reverse:
        ref_ids = ref_ids[::-1]
    render_fn = viewer.gaussians_render_fn(viewer.targets_background())
    meta = {"source": "viewer", "trajectory": spec_meta(spec)}
    return src.restore.queue(key, spec.name, frame,
                             lambda: restore_request(render_fn, scene, cams, frame, ref_ids, spec_meta(spec)), meta)


def viewer_clip_key(base: str, spec) -> str:
    """Cache key of a clip restored in the viewer: the pipeline's name of the clip (``base``:
    ``RestoreCache.key`` with scene camera ids, or the trajectory's own name) with the viewer's
    trajectory settings after it. A viewer clip therefore never replaces a pipeline pseudo-target
    of that pair and frame (which an edited amplitude or frame count would misname), and two
    edits of one pair keep two clips."""
    tag = f"_viewer_A{float(spec.amplitude):.3f}_F{int(spec.n_frames)}" + ("_rev" if spec.reverse else "")
    return base + tag


def _nearest_train(scene, cam) -> int:
    d = [float(((scene.cameras[i].center - cam.center) ** 2).sum()) for i in scene.train_ids]
    return scene.train_ids[int(min(range(len(d)), key=d.__getitem__))]


def restorer_choice(viewer, src) -> None:
    """The restorer kind for new jobs (learned | warp | cogvideo). A kind that cannot be built
    here (no learned weights in RUN/restorer, no GPU for cogvideo) is reported and the current
    restorer stays."""
    from fixer4d.restore.config import KINDS

    current = src.restore.kind
    leave_room_for_label("restorer", at_most=140)
    changed, idx = combo_fit("restorer", KINDS.index(current) if current in KINDS else 0, list(KINDS),
                             "learned: the trained restorer (RUN/restorer); warp: geometric warp of the reference "
                             "views (CPU, no weights); cogvideo: the video diffusion restorer (GPU)", viewer)
    viewer.record_item("restorer_kind")
    if changed and KINDS[idx] != current:
        src.restore.set_jobs(viewer.services.make_jobs(KINDS[idx], src.cache, src.run_dir), KINDS[idx])
        viewer.state.status = f"restorer: {KINDS[idx]} for new jobs"
