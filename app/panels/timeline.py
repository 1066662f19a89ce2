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
        tip("one frame back", viewer)
        imgui.same_line()
        if imgui.arrow_button("##next", imgui.Dir.right):
            st.set_frame(st.frame + 1)
        tip("one frame on", viewer)
        imgui.same_line()
        _, st.loop = imgui.checkbox("loop", st.loop)
        tip("start again at the end", viewer)
        imgui.same_line()
        imgui.set_next_item_width(120)
        _, st.fps = imgui.slider_float("fps", st.fps, *FPS_RANGE, "%.0f")
        tip("playback speed in frames per second (the scene's own rate at start)", viewer)
        clock = f"t = {st.time:.4f}   ({st.num_frames} frames)"
        imgui.same_line(0.0, 3.0 * imgui.get_style().item_spacing.x)
        if imgui.calc_text_size(clock).x > imgui.get_content_region_avail().x:
            imgui.new_line()
        imgui.text(clock)
        imgui.set_next_item_width(-1)
        changed, f = imgui.slider_int("##frame", st.frame, 0, max(st.num_frames - 1, 0), "frame %d")
        viewer.record_item("frame_slider")
        tip("drag to scrub through the clip (the time t = frame / frames drives every panel)", viewer)
        if changed:
            st.set_frame(f)
