"""What the viewer shows where no Gaussian lies: black by default (holes stand out), white, or the
run's own background (``training.background`` resolved for its scene), chosen in View & edit and
kept in the session. Restorations and Compare render over the run's background whatever the view
shows, so a render and its pseudo-target are made alike."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from app.panels import compare
from app.sources import initial_state, run_background
from app.state import AppState
from app.viewer import ViewerSource
from fixer4d.errors import InputError
from fixer4d.pipeline.config import resolve
from fixer4d.scene import load_scene
from fixer4d.train.background import train_views_mean
from viewer_helpers import gl_ctx, make_viewer, scene_gaussians  # noqa: F401 (fixtures)

RUN_RGB = (0.2, 0.4, 0.6)


@pytest.fixture(scope="module")
def tiny():
    return load_scene("tiny")


def test_choose_background_modes_and_session(tmp_path):
    st = AppState()
    assert st.background_mode == "black" and st.background == (0.0, 0.0, 0.0)
    st.choose_background("run", RUN_RGB)
    assert (st.background_mode, st.background) == ("run", RUN_RGB)
    st.choose_background("white", RUN_RGB)
    assert st.background == (1.0, 1.0, 1.0)
    st.choose_background("run", None)  # a bare model has no run background: black, said as black
    assert (st.background_mode, st.background) == ("black", (0.0, 0.0, 0.0))
    with pytest.raises(InputError, match="not one of"):
        st.choose_background("grey", RUN_RGB)
    st.choose_background("run", RUN_RGB)
    path = st.save_session(tmp_path / "session.json")
    back = AppState()
    assert back.load_session(path) and back.background_mode == "run"


def test_run_background_is_the_configs_resolved_for_the_scene(tiny):
    assert run_background(None, tiny) == train_views_mean(tiny)  # live training: the default config (mean)
    black = resolve(overrides={"training.background": [0, 0, 0]})
    assert run_background(black, tiny) == (0.0, 0.0, 0.0)


@pytest.mark.gl
def test_view_shows_the_chosen_background_and_compare_renders_over_the_runs(make_viewer, tiny):
    src = ViewerSource(scene=tiny, label="tiny", background=RUN_RGB)
    st = initial_state(src, scene_gaussians(tiny))
    st.show_frusta = st.show_trajectories = False
    centre = np.mean([c.center for c in tiny.cameras], axis=0)
    st.view.look_from(centre, centre - 10.0 * (np.mean([c.center for c in tiny.train_cameras], axis=0) - centre))
    d = make_viewer(st, src)
    v = d.viewer
    assert "background" in v.item_rects  # the combo is drawn in View & edit
    for mode, want in (("black", (0, 0, 0)), ("run", RUN_RGB), ("white", (1, 1, 1))):
        st.choose_background(mode, src.background)
        d.settle()
        x0, y0, w, h = (int(a) for a in v.viewport_rect)
        shot = v.screenshot(d.fbo)[y0:y0 + h, x0:x0 + w].reshape(-1, 3).astype(float)
        np.testing.assert_allclose(np.median(shot, axis=0), np.round(np.asarray(want) * 255), atol=1.0)
    # Compare: over the run's background while the view shows white (a camera turned half away
    # from the scene, so part of its frame is empty)
    cam = tiny.cameras[0]
    far = cam.with_pose(cam.c2w @ np.array([[np.cos(1.2), 0, np.sin(1.2), 0], [0, 1, 0, 0],
                                             [-np.sin(1.2), 0, np.cos(1.2), 0], [0, 0, 0, 1]]))
    entry = SimpleNamespace(key="k", round=0, cameras=[far], time=0.0, frame=0,
                            rgb=lambda: np.zeros((1, cam.height, cam.width, 3), np.float32), meta={})
    imgs = compare.frame_images(v, {"cache": {}}, entry, 0)
    want = v.gaussians_render_fn(RUN_RGB)(far, 0.0)["rgb"]
    np.testing.assert_array_equal(imgs["render"], want)
    assert not np.array_equal(want, v.gaussians_render_fn()(far, 0.0)["rgb"])  # the view's white differs
