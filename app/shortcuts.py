"""The viewer's keyboard shortcuts and its first-launch hint (the viewer acts on them, the Help
window lists them)."""
from __future__ import annotations

# (key, ctrl) -> (action, what the Help window says). Handled when the key goes down, however
# short the press (``app.viewer.Viewer.key_event``).
SHORTCUTS = {("z", True): ("undo", "undo the last edit"), ("y", True): ("redo", "redo"),
             ("o", True): ("open", "open a run folder, model, scene or folder of videos"),
             ("s", True): ("save", "save the edits as a new model version"), ("q", True): ("quit", "quit"),
             ("space", False): ("play", "play / pause the timeline")}
FIRST_LAUNCH_HINT = ("drag: orbit   right-drag: pan   wheel: zoom   space: play   Ctrl+Z: undo   "
                     "Help > Mouse and keys for the rest")
