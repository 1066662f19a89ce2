"""The docked panels. Each module has ``draw(viewer)``; PANELS lists them in menu order."""
from __future__ import annotations

from app.panels import compare, debug, restore, timeline, training, trajectories, view

PANELS = [("view", view.draw), ("timeline", timeline.draw), ("trajectories", trajectories.draw),
          ("restore", restore.draw), ("compare", compare.draw), ("training", training.draw),
          ("debug", debug.draw)]
