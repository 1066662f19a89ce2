"""The viewer's questions: unsaved edits on close (save / discard / cancel) and, at launch,
whether to restore autosaved edits."""
from __future__ import annotations

from imgui_bundle import imgui

from app.panels._layout import tip

CLOSE_POPUP = "Unsaved edits##close"
AUTOSAVE_POPUP = "Restore edits?##autosave"


def draw(viewer) -> None:
    _close_prompt(viewer)
    _autosave_prompt(viewer)


def _modal(name: str, wanted: bool) -> bool:
    if wanted and not imgui.is_popup_open(name):
        imgui.open_popup(name)
    return imgui.begin_popup_modal(name, None, imgui.WindowFlags_.always_auto_resize.value)[0]


def _close_prompt(viewer) -> None:
    if not _modal(CLOSE_POPUP, viewer.close_prompt):
        return
    st = viewer.state
    imgui.text(f"The model has unsaved edits ({len(st.undo_stack)} in the undo history).")
    imgui.text("Save them as a new model version before closing?")
    choice = None
    if imgui.button("save"):
        choice = "save"
    viewer.record_item("close_save")
    tip("write them as RUN/model_edit_<k>.ply, then close", viewer)
    imgui.same_line()
    if imgui.button("discard"):
        choice = "discard"
    viewer.record_item("close_discard")
    tip("close without saving: the edits and their autosave are gone (this cannot be undone)", viewer)
    imgui.same_line()
    if imgui.button("cancel") or imgui.is_key_pressed(imgui.Key.escape, False):
        choice = "cancel"
    viewer.record_item("close_cancel")
    tip("keep working (Esc)", viewer)
    if choice is not None:
        viewer.answer_close(choice)
        imgui.close_current_popup()
    imgui.end_popup()


def _autosave_prompt(viewer) -> None:
    offer = viewer.autosave_offer
    if not _modal(AUTOSAVE_POPUP, offer is not None):
        return
    if offer is None:  # answered elsewhere (a test, a new source)
        imgui.close_current_popup()
        imgui.end_popup()
        return
    removed = int(offer.get("base_count", 0)) - len(offer.get("keep", []))
    imgui.text(f"Unsaved edits of {offer.get('base')} were kept at {offer.get('saved_at', 'an earlier session')}:")
    imgui.text(f"{len(offer.get('edits', []))} edits, {removed} Gaussians removed.")
    done = False
    if imgui.button("restore them"):
        viewer.restore_autosave()
        done = True
    viewer.record_item("autosave_restore")
    tip("apply the kept edits to the model shown, as one edit (Ctrl+Z undoes it)", viewer)
    imgui.same_line()
    if imgui.button("discard them"):
        viewer.discard_autosave()
        done = True
    viewer.record_item("autosave_discard")
    tip("delete the kept edits (the autosave file); the model stays as saved (this cannot be undone)", viewer)
    if done:
        imgui.close_current_popup()
    imgui.end_popup()
