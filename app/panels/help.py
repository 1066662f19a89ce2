"""Help: the Help menu and its "Mouse and keys" window (every binding the viewer has)."""
from __future__ import annotations

from imgui_bundle import imgui

from app.panels._layout import panel, tip

MOUSE = (("left-drag in the 3D view", "orbit (fly mode: look around)"),
         ("right-drag", "pan"), ("wheel", "zoom"),
         ("W A S D Q E (fly mode, mouse over the view)", "move forward / left / back / right / down / up"),
         ("box tool: drag", "select the Gaussians on the front surface in the box (Shift adds)"),
         ("box tool + 'select through'", "select everything in the box, hidden ones included"),
         ("brush tool: drag", "add the Gaussians under the brush"),
         ("B (Compare, A/B mode)", "switch render / pseudo-target"))


def bindings() -> list[tuple[str, str]]:
    """(input, what it does) for every key and mouse binding, keys first."""
    from app.shortcuts import SHORTCUTS

    keys = [(("Ctrl+" if ctrl else "") + key.upper() if len(key) == 1 else ("Ctrl+" if ctrl else "") + key, text)
            for (key, ctrl), (_, text) in SHORTCUTS.items()]
    return keys + list(MOUSE)


def draw_menu(viewer) -> None:
    opened = imgui.begin_menu("Help")
    viewer.record_item("menu_help")
    if not opened:
        return
    if imgui.menu_item("Mouse and keys", "", viewer.show_help)[0]:
        viewer.show_help = not viewer.show_help
    viewer.record_item("menu_help_keys")
    if imgui.menu_item("Show the first-launch hint", "", False)[0]:
        from app.shortcuts import FIRST_LAUNCH_HINT

        viewer.hint = FIRST_LAUNCH_HINT
    imgui.end_menu()


def draw(viewer) -> None:
    if not viewer.show_help:
        return
    with panel(viewer, "help", "Mouse and keys", 420, 120, 600, 330, front=True) as expanded:
        if not expanded:
            return
        # both columns wrap: a narrow window makes rows taller, never cuts a binding
        if imgui.begin_table("bindings", 2, imgui.TableFlags_.row_bg.value | imgui.TableFlags_.borders_inner_v.value):
            for what, does in bindings():
                imgui.table_next_row()
                imgui.table_next_column()
                imgui.text_wrapped(what)
                imgui.table_next_column()
                imgui.text_wrapped(does)
            imgui.end_table()
        close = imgui.button("close")
        tip("hide this window (Help > Mouse and keys shows it again)", viewer)
        if close:
            viewer.show_help = False
