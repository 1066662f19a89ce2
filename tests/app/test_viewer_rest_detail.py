"""Full detail whenever the camera rests, live training included: a model the trainer publishes
while the camera rests is drawn at once with every splat at full size (the status line says so,
with the step), and level of detail stays for camera motion."""
from __future__ import annotations

import time

import pytest

from app.session import TrainingSession, live_stage1_trainer
from app.sources import initial_state
from app.view3d import FULL_DETAIL
from app.viewer import ViewerSource
from fixer4d.scene import load_scene
from viewer_helpers import gl_ctx, make_viewer  # noqa: F401 (fixtures)

pytestmark = pytest.mark.gl
# Bound on waiting for the live trainer (setup: a sparse init of the tiny scene, then a step); a
# loaded machine may be slow, the test counts frames and steps, not seconds.
TRAINER_WAIT_S = 300.0


def _next_model(training: TrainingSession, seen: int) -> None:
    """Wait until the trainer has published a model after mailbox serial ``seen``."""
    deadline = time.monotonic() + TRAINER_WAIT_S
    got = training.models.take(seen)
    while got is None and training.state in ("idle", "setup", "running") and time.monotonic() < deadline:
        time.sleep(0.005)
        got = training.models.take(seen)
    assert got is not None, f"the trainer published no model ({training.state}: {training.error})"


def test_resting_camera_shows_every_splat_at_full_size_while_training(make_viewer):
    scene = load_scene("tiny")
    # the live trainer the viewer builds for a scene (the pipeline's stage 1), publishing every step
    training = TrainingSession(lambda report: live_stage1_trainer(scene, 10 ** 4, "sparse", 2, report),
                               publish_every=1, publish_min_s=0.0)
    src = ViewerSource(scene=scene, label="tiny (live training)", training=training)
    d = make_viewer(initial_state(src, None), src)
    v = d.viewer
    training.start()
    try:
        _next_model(training, 0)
        v.last_input = time.monotonic()  # interacting: every published model is taken
        d.frame(2)
        assert v.state.gaussians is not None
        # an orbit on a slow GL: level of detail while the camera moves (the check can fail)
        x0, y0, x1, y1 = v.window_rects["viewport"]
        cx, cy = (x0 + x1) / 2, (y0 + y1) / 2
        d.move(cx, cy)
        d.button(True)
        moving = []
        for k in range(1, 5):
            v.adaptive.full_cost_ms = 1e6
            d.move(cx + 15 * k, cy)
            moving.append((v.view_mode, v.render_camera.width < v.display_camera.width))
        assert all(m.startswith("moving: level of detail") and reduced for m, reduced in moving[1:]), moving
        d.button(False)  # the camera rests from here on
        # every frame from the first one at rest: a new training model, drawn in full at once
        for _ in range(5):
            _next_model(training, v._model_serial)  # newer than the model the viewer shows
            shown = v.state.gaussians
            v.last_input = time.monotonic()
            v.adaptive.full_cost_ms = 1e6  # as slow as during the orbit
            d.frame()
            assert v.state.gaussians is not shown  # a model published after the camera stopped
            assert v.view_mode.startswith(FULL_DETAIL) and "training step" in v.view_mode, v.view_mode
            assert v.splats.stats.fraction == 1.0 and v.splats.stats.instances == v.state.gaussians.n
            assert (v.render_camera.width, v.render_camera.height) == (v.display_camera.width,
                                                                       v.display_camera.height)
        assert training.state == "running" and "status_mode" in v.item_rects  # the status line shows it
    finally:
        training.stop()
