"""Default placement of a panel the first time it appears (later the imgui ini layout wins)."""
from __future__ import annotations

from imgui_bundle import imgui

# The default layout is designed for this window size and scaled to the actual one.
DESIGN_SIZE = (1440.0, 900.0)


def begin(title: str, x: float, y: float, w: float, h: float) -> bool:
    """imgui.begin with a first-use position/size given in DESIGN_SIZE pixels (scaled to the
    window); returns whether the body should be drawn (call imgui.end() either way)."""
    place(x, y, w, h)
    expanded, _ = imgui.begin(title)
    return expanded


def show_error(viewer, name: str) -> None:
    err = viewer.panel_errors.get(name)
    if err:
        imgui.text_colored(imgui.ImVec4(1.0, 0.35, 0.3, 1.0), err)


def place(x: float, y: float, w: float, h: float) -> None:
    """First-use position and size of the next window, in DESIGN_SIZE pixels."""
    size = imgui.get_io().display_size
    sx, sy = size.x / DESIGN_SIZE[0], size.y / DESIGN_SIZE[1]
    imgui.set_next_window_pos(imgui.ImVec2(x * sx, y * sy), imgui.Cond_.first_use_ever.value)
    imgui.set_next_window_size(imgui.ImVec2(w * sx, h * sy), imgui.Cond_.first_use_ever.value)
