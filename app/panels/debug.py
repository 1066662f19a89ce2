"""Debug overlays: hole map (low accumulated alpha), blur map (missing detail against the
nearest reference), undetermined map (the model and its twin field disagree), depth, accumulated
alpha, per-Gaussian heatmaps (speed, temporal opacity); frame timings; screenshot export."""
from __future__ import annotations

import numpy as np
from imgui_bundle import imgui

from app.panels._layout import leave_room_for_label, panel, radio_row, same_line_if_fits, tip
from app.undetermined import twin_note

RESOLVE = ("color", "holes", "depth", "alpha", "blur", "undetermined")
# Image modes whose pixels do not show the splat colours (the Gaussian colour modes are greyed out).
SPLAT_COLOUR_REPLACED = ("depth", "holes", "alpha")
SPLAT = ("color", "speed", "temporal_opacity")
IMAGE_TIPS = {"color": "the rendered colours", "holes": "red where the accumulated opacity is below 0.5 (holes)",
              "depth": "depth of each pixel, near red .. far blue (colour bar in scene units)",
              "alpha": "accumulated opacity of each pixel, 0 .. 1",
              "blur": "missing detail against the nearest train camera's real frame (recomputed when the view rests)",
              "undetermined": "where the model and its twin field disagree, 0 .. 1: the train views do not determine "
                              "the scene there (recomputed when the view rests)",
              "moving": "the init's moving-content mask, magenta, when snapped to a masked camera and frame"}
SPLAT_TIPS = {"color": "each Gaussian in its own colour",
              "speed": "each Gaussian coloured by its speed |dmu/dt| (scene units per second, colour bar)",
              "temporal_opacity": "each Gaussian coloured by its temporal opacity at the current time, 0 .. 1"}


def draw(viewer) -> None:
    st = viewer.state
    ui = viewer.__dict__.setdefault("_debug_ui", {"shot": "viewer/screenshot.png", "ref": None})
    with panel(viewer, "debug", "Debug", 1105, 600, 330, 295) as expanded:
        if not expanded:
            return
        imgui.text("image")
        tip("what each pixel shows: colour, holes (low opacity), depth, accumulated opacity, blur (missing "
            "detail vs the nearest real view), undetermined (the model and its twin field disagree), moving "
            "content (init masks)", viewer)
        modes = RESOLVE + (("moving",) if viewer.masks() is not None else ())
        no_twin = twin_note(viewer)  # why the undetermined mode is greyed out, and the way to a twin
        tips = {**IMAGE_TIPS, "undetermined": no_twin} if no_twin else IMAGE_TIPS
        mode = radio_row(modes, st.debug_mode, "image", tips, viewer, disabled=("undetermined",) if no_twin else ())
        if mode != st.debug_mode:
            st.debug_mode = mode
            if mode == "blur":
                compute_blur(viewer)
        if st.debug_mode == "blur":
            recompute = imgui.button("recompute blur map")
            tip("compute the blur map again for this view against the nearest train camera's real frame", viewer)
            if recompute:
                compute_blur(viewer)
            if ui["ref"] is not None:
                same_line_if_fits(imgui.calc_text_size(f"vs {ui['ref']}").x)
                imgui.text(f"vs {ui['ref']}")
        if st.debug_mode == "undetermined" and not no_twin:
            first, twin = viewer.twin_pair()
            imgui.text(f"vs {twin.name}" if first is None else "stage-1 field 1 vs field 2")
            tip("the twin field the shown model is compared with (the second field co_fields trained)" if first is None
                else "the run's two stage-1 fields (other seeds) compared with each other", viewer)
        imgui.text("Gaussians")
        tip("colour each Gaussian by its colour, speed or temporal opacity", viewer)
        # depth and holes replace the splats' colours: a Gaussian colour mode would change nothing
        replaced = st.debug_mode in SPLAT_COLOUR_REPLACED
        tips = {m: f"the image mode '{st.debug_mode}' does not show the Gaussians' colours" for m in SPLAT} \
            if replaced else SPLAT_TIPS
        imgui.begin_disabled(replaced)
        st.splat_mode = radio_row(SPLAT, st.splat_mode, "splat", tips, viewer)
        imgui.end_disabled()
        viewer.record_item("splat_modes")
        s = viewer.splats.stats
        imgui.text_wrapped(f"frame {viewer.frame_ms:.1f} ms   draw {s.draw_ms:.1f} ms   sort {s.sort_ms:.1f} ms   "
                           f"upload {s.upload_ms:.1f} ms   instances {s.instances}")
        leave_room_for_label("file")
        _, ui["shot"] = imgui.input_text("file", ui["shot"])
        tip("where the screenshot goes: a path relative to the run (or session) folder, or a full path", viewer)
        save = imgui.button("save screenshot (3D view)")
        tip("write the 3D view's current image (without the panels) to the file above", viewer)
        if save:
            save_view_png(viewer, ui["shot"])


def compute_blur(viewer) -> None:
    """Blur map of the current view against the nearest train camera's real frame."""
    from app.debug_maps import blur_map, nearest_camera

    scene, cam = viewer.source.scene, viewer.splats.last_camera
    ui = viewer.__dict__.setdefault("_debug_ui", {"shot": "viewer/screenshot.png", "ref": None})
    if scene is None or cam is None:
        viewer.state.status = "blur map needs a scene with real frames"
        return
    train = scene.train_cameras
    j = nearest_camera(train, cam)
    ref_idx = scene.train_ids[j]
    m = blur_map(viewer.splats.read_rgb(viewer.state.background), viewer.splats.read_depth(),
                 viewer.splats.read_alpha(), cam, scene.frame(viewer.state.frame, ref_idx), train[j])
    viewer.show_scalar_map(m, viewer.view_signature())
    viewer.blur_max = float(max(np.percentile(m, 99), 1e-6))
    ui["ref"] = train[j].name or str(ref_idx)


def save_view_png(viewer, text: str) -> None:
    """Write the 3D view's last image; a relative path lands in the run/session folder."""
    from PIL import Image

    from fixer4d.atomic import atomic_path

    if viewer.splats.display_texture is None:
        viewer.state.status = "nothing rendered yet"
        return
    path = viewer.output_path(text)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        Image.fromarray(viewer.splats.read_display()).save(tmp)
    viewer.state.status = f"wrote {path}"
