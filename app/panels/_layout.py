"""Panel plumbing: first-use placement, the guard every panel body runs in, and widgets that
keep the layout still (elided one-line paths, fixed-height status slots).

``panel(viewer, name, title, x, y, w, h)`` opens the panel's window and yields whether its body
should be drawn. Whatever the body raises (a bad file, a bug, an imgui assertion such as an
unbalanced push/pop) is caught there: imgui's error recovery closes everything the body opened
(child windows, groups, ID and style stacks, disabled blocks) plus the panel's own window, the
error goes to the viewer's notifications area and the log, and the frame goes on. Nothing else
in the frame is lost. Every panel reserves its vertical scrollbar, so content that grows past
the bottom never narrows (and re-wraps) what is above it.
"""
from __future__ import annotations

from contextlib import contextmanager
from typing import Iterator

from imgui_bundle import imgui

# The default layout is designed for this window size and scaled to the actual one.
DESIGN_SIZE = (1440.0, 900.0)


def overlaps(a: tuple, b: tuple) -> bool:
    """Whether two screen rectangles (x0, y0, x1, y1) share any area."""
    return a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3]


def alone(viewer, name: str) -> bool:
    """Whether panel ``name``'s window overlapped no other panel's window last frame."""
    rects = viewer.last_window_rects
    rect = rects.get(name)
    return rect is not None and not any(overlaps(rect, r) for other, r in rects.items() if other != name)


def place(viewer, name: str, x: float, y: float, w: float, h: float) -> None:
    """Position and size of panel ``name``'s next window: on first use (x, y, w, h) in DESIGN_SIZE
    pixels scaled to the window; after the app window was resized, the panel's own last rectangle
    scaled by the same factors (``rescale_layout``), so the user's arrangement keeps filling it."""
    pending = viewer.pending_window_rects.pop(name, None)
    if pending is not None:
        x0, y0, x1, y1 = pending
        imgui.set_next_window_pos(imgui.ImVec2(x0, y0), imgui.Cond_.always.value)
        imgui.set_next_window_size(imgui.ImVec2(x1 - x0, y1 - y0), imgui.Cond_.always.value)
        return
    size = imgui.get_io().display_size
    sx, sy = size.x / DESIGN_SIZE[0], size.y / DESIGN_SIZE[1]
    imgui.set_next_window_pos(imgui.ImVec2(x * sx, y * sy), imgui.Cond_.first_use_ever.value)
    imgui.set_next_window_size(imgui.ImVec2(w * sx, h * sy), imgui.Cond_.first_use_ever.value)


def rescale_layout(viewer, old: tuple[float, float], new: tuple[float, float]) -> None:
    """The app window went from ``old`` to ``new`` (width, height) pixels: every floating panel
    seen so far is due at its last rectangle scaled by new / old (placed when it next draws, so a
    hidden panel follows too). Docked panels are left to their dock node, which resizes itself."""
    sx, sy = new[0] / old[0], new[1] / old[1]
    for name, known in viewer.known_window_rects.items():
        if not viewer.docked_windows.get(name, False):
            # a panel still hidden since the last resize has its due rectangle in the old size
            x0, y0, x1, y1 = viewer.pending_window_rects.get(name, known)
            viewer.pending_window_rects[name] = (x0 * sx, y0 * sy, x1 * sx, y1 * sy)


def recover(saved) -> None:
    """Close what was opened since ``saved`` (an ``ErrorRecoveryState``), quietly: the exception
    that interrupted the block is reported to the user, so imgui's own "Missing End()" lines
    for the unwinding would only repeat it on stderr every frame."""
    io = imgui.get_io()
    was_logging, io.config_error_recovery_enable_debug_log = io.config_error_recovery_enable_debug_log, False
    try:
        imgui.internal.error_recovery_try_to_recover_state(saved)
    finally:
        io.config_error_recovery_enable_debug_log = was_logging


@contextmanager
def guard(viewer, name: str) -> Iterator[None]:
    """Run a block of imgui calls; on any exception restore imgui's stacks to what they were
    when the block began and report the error as coming from ``name``."""
    saved = imgui.internal.ErrorRecoveryState()
    imgui.internal.error_recovery_store_state(saved)
    try:
        yield
    except Exception as exc:  # the app keeps running; the user reads what went wrong
        recover(saved)
        viewer.report_error(name, exc)


@contextmanager
def panel(viewer, name: str, title: str, x: float, y: float, w: float, h: float,
          front: bool = False) -> Iterator[bool]:
    """``with panel(...) as expanded: if expanded: <body>``: the panel window (first-use
    placement in DESIGN_SIZE pixels) with its body guarded; ``imgui.end`` is always called
    exactly once, by the guard's recovery or here. ``front``: a window shown on demand (Help,
    the report, notifications) comes to the front when it appears, over the panels it covers.

    A window that overlapped no other last frame draws no background: the frame is cleared to
    the window colour, and on a software GL every full-area fill costs (llvmpipe, 1440x900: one
    window's background ~25-50 ms, the default layout's panels ~90 ms in all, load 1-5).
    """
    saved = imgui.internal.ErrorRecoveryState()
    imgui.internal.error_recovery_store_state(saved)
    place(viewer, name, x, y, w, h)
    if front and name not in viewer.last_window_rects:
        imgui.set_next_window_focus()
    if alone(viewer, name):
        imgui.set_next_window_bg_alpha(0.0)
    try:
        expanded, _ = imgui.begin(title, None, imgui.WindowFlags_.always_vertical_scrollbar.value)
        pos, size = imgui.get_window_pos(), imgui.get_window_size()
        viewer.item_rects[f"window_{name}"] = viewer.window_rects[name] = viewer.known_window_rects[name] = (
            pos.x, pos.y, pos.x + size.x, pos.y + size.y)
        viewer.docked_windows[name] = imgui.is_window_docked()
        yield expanded
    except Exception as exc:
        recover(saved)  # ends the panel window too
        viewer.report_error(name, exc)
    else:
        imgui.end()
        viewer.panel_errors.pop(name, None)


def tip(text: str, viewer=None) -> None:
    """A tooltip for the widget just submitted, shown while the mouse rests on it (``viewer``:
    also noted as ``viewer.tooltip_shown``, which tests read)."""
    if imgui.is_item_hovered(imgui.HoveredFlags_.for_tooltip.value):
        imgui.set_tooltip(text)
        if viewer is not None:
            viewer.tooltip_shown = text


def error_text(text: str) -> None:
    """A line of error-coloured wrapped text."""
    imgui.push_style_color(imgui.Col_.text.value, imgui.ImVec4(1.0, 0.4, 0.35, 1.0))
    imgui.text_wrapped(text)
    imgui.pop_style_color()


def error_text_line(text: str, viewer=None) -> None:
    """``one_line`` in the error colour (the whole message on hover)."""
    imgui.push_style_color(imgui.Col_.text.value, imgui.ImVec4(1.0, 0.4, 0.35, 1.0))
    try:
        one_line(text, viewer, disabled=False)
    finally:
        imgui.pop_style_color()


def leave_room_for_label(label: str, at_most: float | None = None) -> None:
    """Make the next widget as wide as the line allows (at most ``at_most`` pixels) less the
    width of its label ``label``, which imgui draws to its right: the label is never cut."""
    style = imgui.get_style()
    room = imgui.calc_text_size(label.split("##")[0]).x + style.item_inner_spacing.x
    width = imgui.get_content_region_avail().x - room
    imgui.set_next_item_width(max(40.0, width if at_most is None else min(width, at_most)))


def combo_fit(label: str, current: int, names: list[str], hint: str, viewer=None,
              none_text: str = "") -> tuple[bool, int]:
    """A combo of ``names`` whose shown choice is elided to its frame, with the tooltip ``hint``
    (plus the whole choice when it is elided; ``none_text`` shows when nothing, -1, is chosen).
    Call after setting the next item width. Returns (changed, index)."""
    style = imgui.get_style()
    room = imgui.calc_item_width() - imgui.get_frame_height() - 2.0 * style.frame_padding.x
    full = names[current] if 0 <= current < len(names) else none_text
    shown = elide(full, room)
    changed, idx = False, current
    opened = imgui.begin_combo(label, shown)
    if not opened:  # (an open combo's popup is the current window)
        tip(hint + (f"\nnow: {full}" if shown != full else ""), viewer)
    else:
        for i, name in enumerate(names):
            if imgui.selectable(name, i == current)[0]:
                changed, idx = True, i
        imgui.end_combo()
    return changed, idx


def button_width(label: str) -> float:
    """Width of a button labelled ``label``."""
    style = imgui.get_style()
    return imgui.calc_text_size(label.split("##")[0]).x + 2.0 * style.frame_padding.x


def toggle_width(label: str) -> float:
    """Width of a radio button or checkbox labelled ``label``."""
    style = imgui.get_style()
    return imgui.get_frame_height() + style.item_inner_spacing.x + imgui.calc_text_size(label.split("##")[0]).x


def same_line_if_fits(width: float) -> None:
    """Put the next item (``width`` pixels) on the current line when it fits before the panel's
    edge, else on a new line: rows of buttons wrap in a narrow window instead of being cut."""
    imgui.same_line()
    if width > imgui.get_content_region_avail().x:
        imgui.new_line()


def radio_row(items: tuple[str, ...] | list[str], current: str, id_suffix: str, tips: dict[str, str],
              viewer=None, disabled: tuple[str, ...] = ()) -> str:
    """Radio buttons for ``items`` laid out left to right, wrapping to a new line instead of
    running past the panel's edge, each with its tooltip ``tips[item]`` (shown on the
    ``disabled`` ones too, greyed out: say there why); returns the chosen item."""
    style = imgui.get_style()
    right = imgui.get_cursor_screen_pos().x + imgui.get_content_region_avail().x
    chosen = current
    for k, item in enumerate(items):
        width = imgui.get_frame_height() + style.item_inner_spacing.x + imgui.calc_text_size(item).x
        if k:
            imgui.same_line()
            if imgui.get_cursor_screen_pos().x + width > right:
                imgui.new_line()
        imgui.begin_disabled(item in disabled)
        if imgui.radio_button(f"{item}##{id_suffix}", item == current):
            chosen = item
        imgui.end_disabled()
        tip(tips[item], viewer)
    return chosen


def elide(text: str, width: float) -> str:
    """``text`` shortened in the middle ("/home/me/.../viewer/videos/a.mp4") to fit ``width``
    pixels in the current font; unchanged when it fits."""
    if imgui.calc_text_size(text).x <= width:
        return text
    lo, hi = 0, len(text)  # the most characters kept (half each side) that still fit
    while lo < hi:
        mid = (lo + hi + 1) // 2
        if imgui.calc_text_size(text[: (mid + 1) // 2] + "..." + text[len(text) - mid // 2:]).x <= width:
            lo = mid
        else:
            hi = mid - 1
    return text[: (lo + 1) // 2] + "..." + (text[len(text) - lo // 2:] if lo // 2 else "")


def one_line(text: str, viewer=None, disabled: bool = True, hint: str = "") -> None:
    """``text`` (a path, a message) on exactly one line, elided in the middle to the space left
    on the line; when shortened, the mouse over it shows it whole (plus ``hint``)."""
    shown = elide(text, max(imgui.get_content_region_avail().x, 8.0))
    (imgui.text_disabled if disabled else imgui.text)(shown)
    if shown != text or hint:
        tip("\n".join(t for t in (text if shown != text else "", hint) if t), viewer)
