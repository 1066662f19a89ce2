"""The undetermined overlay: where the shown model and its twin field disagree.

A run trained with ``co_fields`` keeps a second stage-1 field beside its models
(``model_stage1_twin.ply``), and every model of the run is compared with it; a run of several
fields keeps each (``fields/field<k>/model.ply``), and the map compares the first two
(``app.files.twin_pair``). Where the two renders disagree, the train views do not determine
the scene (``fixer4d.restore.undetermined``). The map is computed
for the resting view from two torch renders at the same camera, time and background: the shown
Gaussians (edits included) through ``services.render``, the twin through ``services.render_twin``.
"""
from __future__ import annotations

import numpy as np

from app.files import RUN_TWIN

# How to get a twin field, for the tooltip and the legend of a model without one.
HOW_TO_GET_A_TWIN = "fixer4d run ... --set training.fields=2"
# Map value from which a pixel counts in the legend's share: half weight, where the colour
# difference reaches the library's "different surface" level (COLOUR_LOW..HIGH's centre).
UNDETERMINED_LEVEL = 0.5
# Longest side (pixels) of the two renders: two torch renders of the demo's 20k Gaussians take
# ~0.1 s at 800 px on a CPU against ~0.8 s at 1600; the map is smooth (a 5 px box) and the GL
# texture stretches it over the view.
MAX_SIDE = 800


def twin_note(viewer) -> str:
    """"" when the shown model has a twin field; else why not and how to get one."""
    model = viewer.source.model_path
    if viewer.twin_pair() is not None:
        return ""
    if model is None:
        return f"no twin field: open a run trained with\n{HOW_TO_GET_A_TWIN}"
    if model.name == RUN_TWIN:
        return "this is the run's twin field: open another\nversion of the run to compare it with"
    return f"{model.name} has no twin field; a run trained with\n{HOW_TO_GET_A_TWIN} has one"


def compute_undetermined(viewer) -> None:
    """The undetermined map of the current view: the shown Gaussians (or a run's first field) and
    the twin field rendered at the view's camera and model time, compared by ``undetermined_map``; uploads it (values
    0..1, the colour scale's fixed range) and sets ``viewer.undetermined_share``."""
    from fixer4d.restore.undetermined import undetermined_map

    cam, pair = viewer.render_camera, viewer.twin_pair()
    if cam is None or pair is None:
        viewer.state.status = twin_note(viewer) or "undetermined map: nothing rendered yet"
        return
    if max(cam.width, cam.height) > MAX_SIDE:
        cam = cam.scaled(MAX_SIDE / max(cam.width, cam.height))
    st, t = viewer.state, viewer.model_time()
    first, twin = pair
    render_file = viewer.services.render_twin
    a = (viewer.gaussians_render_fn() if first is None
         else render_file(first, tuple(st.background), viewer.source.render_backend))(cam, t)
    b = render_file(twin, tuple(st.background), viewer.source.render_backend)(cam, t)
    m = undetermined_map(a["rgb"], b["rgb"], a["alpha"], b["alpha"])
    viewer.show_scalar_map(m, viewer.view_signature())
    viewer.undetermined_share = float(np.mean(m >= UNDETERMINED_LEVEL))
