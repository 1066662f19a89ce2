"""Full detail whenever the camera rests, live training included: a model the trainer publishes
while the camera rests is drawn at once with every splat at full size (the status line says so,
with the step), and level of detail stays for camera motion."""
from __future__ import annotations

import time
from types import SimpleNamespace

import pytest

from app.session import TrainingSession
from app.sources import initial_state
from app.view3d import FULL_DETAIL
from app.viewer import ViewerSource
from viewer_helpers import gl_ctx, make_gaussians, make_viewer  # noqa: F401 (fixtures)

pytestmark = pytest.mark.gl
# Bound on waiting for the trainer thread to take a step (a loaded machine may be slow).
STEP_WAIT_S = 60.0


class StepTrainer:
    """A trainer whose steps change nothing but the step count; each step publishes its model."""

    def __init__(self, model) -> None:
        self.model, self.step_count, self.done = model, 0, False
        self.config = SimpleNamespace(iterations=10 ** 9)

    def step(self) -> dict:
        self.step_count += 1
        time.sleep(0.005)
        return {"loss": 1.0 / self.step_count}


def _next_step(training: TrainingSession, after: int) -> int:
    deadline = time.monotonic() + STEP_WAIT_S
    while training.step <= after and time.monotonic() < deadline:
        time.sleep(0.005)
    assert training.step > after, "the trainer took no step"
    return training.step


def test_resting_camera_shows_every_splat_at_full_size_while_training(make_viewer):
    g = make_gaussians(n_static=2500, n_moving=300)
    training = TrainingSession(lambda report: StepTrainer(g.to_model()), publish_every=1, publish_min_s=0.0)
    src = ViewerSource(label="live", training=training)
    d = make_viewer(initial_state(src, None), src)
    v = d.viewer
    training.start()
    try:
        step = _next_step(training, 0)
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
            moving.append(v.view_mode)
        # (the first move only starts the drag)
        assert all("level of detail" in m and "100% splats" not in m for m in moving[1:]), moving
        d.button(False)  # the camera rests from here on
        # every frame from the first one at rest: a new training model, drawn in full at once
        for _ in range(5):
            step = _next_step(training, step)
            shown = v.state.gaussians
            v.last_input = time.monotonic()
            v.adaptive.full_cost_ms = 1e6  # as slow as during the orbit
            d.frame()
            assert v.state.gaussians is not shown  # a model published after the camera stopped
            assert v.view_mode.startswith(FULL_DETAIL) and "training step" in v.view_mode, v.view_mode
            assert v.splats.stats.fraction == 1.0
            assert (v.render_camera.width, v.render_camera.height) == (v.display_camera.width,
                                                                       v.display_camera.height)
        assert "status_mode" in v.item_rects  # the status line shows it
    finally:
        training.stop()
