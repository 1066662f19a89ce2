"""Timeline: play/pause/loop, scrub, frame step, fps. The time drives the render and every panel."""
from __future__ import annotations

from imgui_bundle import imgui

from app.panels._layout import panel, tip

# Playback speeds offered (frames per second).
FPS_RANGE = (1.0, 120.0)


def draw(viewer) -> None:
    st = viewer.state
    with panel(viewer, "timeline", "Timeline", 300, 505, 800, 95) as expanded:
        if not expanded:
            return
        if imgui.button("Pause" if st.playing else "Play"):
            st.playing = not st.playing
        viewer.record_item("play")
        tip("play / pause (space); with the camera at rest each frame is drawn at full quality once and "
            "replayed from the frame cache", viewer)
        imgui.same_line()
        if imgui.arrow_button("##prev", imgui.Dir.left):
            st.set_frame(st.frame - 1)
        imgui.same_line()
        if imgui.arrow_button("##next", imgui.Dir.right):
            st.set_frame(st.frame + 1)
        imgui.same_line()
        _, st.loop = imgui.checkbox("loop", st.loop)
        tip("start again at the end", viewer)
        imgui.same_line()
        imgui.set_next_item_width(120)
        _, st.fps = imgui.slider_float("fps", st.fps, *FPS_RANGE, "%.0f")
        tip("playback speed in frames per second (the scene's own rate at start)", viewer)
        imgui.same_line(0.0, 3.0 * imgui.get_style().item_spacing.x)
        imgui.text(f"t = {st.time:.4f}   ({st.num_frames} frames)")
        imgui.set_next_item_width(-1)
        changed, f = imgui.slider_int("##frame", st.frame, 0, max(st.num_frames - 1, 0), "frame %d")
        viewer.record_item("frame_slider")
        if changed:
            st.set_frame(f)
