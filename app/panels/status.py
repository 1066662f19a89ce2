"""The status line in the main menu bar: what is open, which image the 3D view shows (full
detail or level of detail) and the latest message, in a fixed order; the source's name gives
way first, then the message, so nothing runs off the window. (The frame time is in the Debug
panel.)"""
from __future__ import annotations

from imgui_bundle import imgui

from app.panels._layout import elide, tip

# Narrowest the source label is squeezed to (pixels) before the message gives way too.
MIN_LABEL_W = 80.0


def draw(viewer) -> None:
    """The status texts after the menus (inside the main menu bar)."""
    unsaved = " (unsaved edits)" if viewer.state.unsaved else ""
    mode = f"[{viewer.view_mode}]"
    line = viewer.state.status or viewer.hint  # the first-launch hint until something has a status
    gap = 2.0 * imgui.get_style().item_spacing.x
    avail = imgui.get_content_region_avail().x - 3.0 * gap
    size = imgui.calc_text_size
    meta = unsaved
    line_w = size(line).x if line else 0.0
    label_w = max(MIN_LABEL_W, avail - size(mode).x - line_w - size(meta).x)
    label = elide(viewer.source.label, label_w)
    line_w = max(0.0, avail - size(label + meta).x - size(mode).x)
    imgui.text_disabled(label + meta)
    viewer.record_item("status_source")
    if label != viewer.source.label:
        tip(viewer.source.label, viewer)
    imgui.same_line(0.0, gap)
    imgui.text_disabled(mode)
    viewer.record_item("status_mode")
    tip("which image the 3D view shows: full quality (every splat at full size, whenever the camera rests), "
        "playback from the frame cache, or level of detail while the camera moves", viewer)
    if line and line_w >= size("...").x:
        shown = elide(line, line_w)
        imgui.same_line(0.0, gap)
        imgui.text_disabled(shown)
        viewer.record_item("status_line")
        if shown != line:
            tip(line, viewer)
