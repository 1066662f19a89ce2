"""Playback at full fidelity: with the camera at rest every frame is drawn once at full quality
and replayed from the frame cache; level of detail only while the camera moves."""
from __future__ import annotations

import numpy as np
import pytest

from app.state import AppState
from app.view3d import FULL_DETAIL
from app.viewer import ViewerSource
from doc_shots import save_shot
from viewer_helpers import gl_ctx, make_gaussians, make_viewer  # noqa: F401 (fixtures)

pytestmark = pytest.mark.gl
FRAMES = 6


def _state(g):
    st = AppState(num_frames=FRAMES, fps=30.0)
    st.view.look_from([0.0, 0.0, -4.0], [0.0, 0.0, 0.0], scene_radius=1.5)
    st.set_gaussians(g)
    return st


def _play(d, frames: int) -> None:
    for _ in range(frames):
        d.frame(dt=1.0001 / d.viewer.state.fps)  # one clip frame per UI frame


def test_playback_from_the_cache_shows_the_full_quality_frame(make_viewer, tmp_path):
    d = make_viewer(_state(make_gaussians(n_static=900, n_moving=120)), ViewerSource(label="test"))
    v, st = d.viewer, d.viewer.state
    paused = {}
    v.use_frame_cache = False  # the reference does not go through the cache
    for f in (2, 4):  # the reference: paused at frame f, resting at full quality
        st.set_frame(f)
        d.settle()
        assert v.adaptive.final and v.view_mode == FULL_DETAIL
        paused[f] = v.shown_image().astype(np.int16)
    v.use_frame_cache = True
    st.set_frame(0)
    d.settle()
    v.adaptive.full_cost_ms = 1e6  # as on a slow GL: anything but the cache would draw a subset
    st.playing = True
    _play(d, FRAMES)  # the first pass fills the cache
    assert len(v.frame_cache) == FRAMES
    for f in (2, 4):
        while st.frame != f:
            _play(d, 1)
        assert "frame cache" in v.view_mode
        diff = np.abs(v.shown_image().astype(np.int16) - paused[f])
        assert diff.mean() < 0.5 and np.percentile(diff, 99.9) <= 2, (diff.mean(), diff.max())
    save_shot(v.screenshot(d.fbo), "viewer_playback_cache", tmp_path)
    # without the cache the same playback draws level of detail, visibly different: the check bites
    v.use_frame_cache = False
    v.frame_cache.clear()
    while st.frame != 1:
        _play(d, 1)
    v.adaptive.full_cost_ms = 1e6
    _play(d, 1)
    assert st.frame == 2 and v.adaptive.scale < 1.0 and "level of detail" in v.view_mode
    assert v.shown_image().shape[0] < paused[2].shape[0]  # a reduced image, not the full-quality one
    # a camera move empties the cache: the next frame is drawn for the new view
    v.use_frame_cache = True
    _play(d, FRAMES)
    assert len(v.frame_cache) > 0
    st.view.rotate(15.0, 0.0, 400)
    _play(d, 1)
    assert len(v.frame_cache) == 0


def test_the_cache_stays_within_its_memory_budget(make_viewer):
    d = make_viewer(_state(make_gaussians(n_static=100, n_moving=20)), ViewerSource(label="test"))
    v = d.viewer
    d.settle()
    w, h = v.display_camera.width, v.display_camera.height
    v.frame_cache.budget_bytes = 3 * 4 * w * h  # three frames
    v.state.playing = True
    _play(d, FRAMES)
    assert len(v.frame_cache) == 3 and v.frame_cache.bytes <= v.frame_cache.budget_bytes
