"""The UI's share of the CPU while live training runs: unattended frames are paced so the UI takes
at most TRAINING_UI_SHARE_UNATTENDED of the time, and published models are taken at most every
MODEL_REFRESH_UNATTENDED_S unless the user interacts."""
from __future__ import annotations

import time
from types import SimpleNamespace

import pytest

import app.main as main
from app.main import TRAINING_UI_FPS, TRAINING_UI_MAX_PAUSE_S, TRAINING_UI_SHARE_UNATTENDED, pace_frame
from app.sources import initial_state
from app.session import TrainingSession
from app.viewer import INTERACTION_S, MODEL_REFRESH_UNATTENDED_S, ViewerSource
from viewer_helpers import gl_ctx, make_gaussians, make_viewer  # noqa: F401 (fixtures)


def _viewer(state: str, last_input: float):
    return SimpleNamespace(source=SimpleNamespace(training=SimpleNamespace(state=state)), last_input=last_input)


def test_unattended_frames_take_a_bounded_share(monkeypatch):
    monkeypatch.setattr(main, "lower_ui_priority", lambda: None)
    waits = []
    pace_frame(_viewer("running", -1e9), time.perf_counter() - 0.05, waits.append)  # a 50 ms frame
    assert 0.05 / (0.05 + waits[0]) <= TRAINING_UI_SHARE_UNATTENDED * 1.05
    waits.clear()
    start = time.perf_counter() - 1.0  # a 1 s frame: the pause is capped (the panels still move)
    pace_frame(_viewer("running", -1e9), start, waits.append)
    assert waits[0] == TRAINING_UI_MAX_PAUSE_S
    waits.clear()
    pace_frame(_viewer("running", time.monotonic()), time.perf_counter() - 0.01, waits.append)
    assert waits[0] == pytest.approx(1.0 / TRAINING_UI_FPS - 0.01, abs=0.005)  # interacting: 10 frames/s
    waits.clear()
    pace_frame(_viewer("paused", -1e9), start, waits.append)
    assert waits == []  # not training: no pacing


@pytest.mark.gl
def test_unattended_viewer_takes_models_at_most_every_refresh(make_viewer):
    training = TrainingSession(lambda report: None)  # never started: the test publishes
    training.state = "running"
    src = ViewerSource(label="live", training=training)
    g = make_gaussians()
    training.models.put(g)
    d = make_viewer(initial_state(src, None), src)
    v = d.viewer
    assert v.state.gaussians is g  # the first model is taken at once
    newer = make_gaussians(seed=1)
    training.models.put(newer)
    d.frame(3)
    assert not v.panel_errors
    assert v.state.gaussians is g  # nobody interacts: it waits for the refresh interval
    v.last_input = time.monotonic()  # the user moves the mouse
    d.frame()
    assert v.state.gaussians is newer
    newest = make_gaussians(seed=2)
    training.models.put(newest)
    v.last_input = time.monotonic() - INTERACTION_S - 1.0
    v._model_taken = time.monotonic() - MODEL_REFRESH_UNATTENDED_S - 1.0  # the interval has passed
    d.frame()
    assert v.state.gaussians is newest


def test_session_pauses_itself_at_the_requested_step(monkeypatch):
    import app.session as session

    class _Trainer:  # counts steps; nothing to train
        def __init__(self):
            self.step_count, self.done, self.model = 0, False, object()

        def step(self):
            self.step_count += 1
            return {"loss": 1.0}

    monkeypatch.setattr(session.GaussianArrays, "from_model", staticmethod(lambda model: model))
    training = TrainingSession(lambda report: _Trainer())
    training.pause_at = 7
    training.start()
    deadline = time.monotonic() + 10
    while training.paused_at_time is None and time.monotonic() < deadline:
        time.sleep(0.01)
    time.sleep(0.2)  # it must stay paused, not run on
    assert training.state == "paused" and training.trainer.step_count == 7 and training.pause_at is None
    training.pause_at = 12
    training.resume()
    while training.trainer.step_count < 12 and time.monotonic() < deadline:
        time.sleep(0.01)
    time.sleep(0.2)
    assert training.trainer.step_count == 12 and training.state == "paused"
    training.stop()
