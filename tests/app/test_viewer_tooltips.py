"""Every control says what it does: a walk through every panel and window of a viewer with all
its content rests the mouse on each interactive item (buttons, checkboxes, radio buttons,
sliders, fields, combos, list entries) and requires a tooltip."""
from __future__ import annotations

import pytest

from fixer4d.scene import load_scene
from ui_walk import PANEL_WINDOWS, Recorder, busy_viewer, walk_window
from viewer_helpers import DEFAULT_WINDOW, gl_ctx, make_viewer  # noqa: F401 (fixtures)

pytestmark = pytest.mark.gl
# Windows that float over the panels: walked one at a time, the others hidden.
FLOATING = {"Notifications": "show_notifications", "Mouse and keys": "show_help", "Run report": "show_report"}


def test_every_interactive_item_has_a_tooltip(make_viewer, tmp_path, monkeypatch):
    scene = load_scene("tiny")
    d = busy_viewer(make_viewer, scene, tmp_path, DEFAULT_WINDOW)
    v = d.viewer
    v.state.trajectories = v.state.trajectories[:5]  # the list shows them all without scrolling
    rec = Recorder(monkeypatch)
    found = {}
    for title in PANEL_WINDOWS:
        for flag in FLOATING.values():
            setattr(v, flag, False)
        if title in FLOATING:
            setattr(v, FLOATING[title], True)
        found[title] = walk_window(d, rec, title)
    counts = {title: len(items) for title, items in found.items()}
    # every panel has its controls (the walk saw them) ...
    assert all(counts[t] >= 1 for t in PANEL_WINDOWS), counts
    assert sum(counts.values()) >= 60, counts
    # ... and each of them a tooltip
    missing = [f"{title}: {kind} {label!r}" for title, items in found.items()
               for (kind, label, _), text in items.items() if not text]
    assert not missing, "\n".join(missing)
