"""CogVideoV2VRestorer: without diffusers/weights/CUDA it refuses clearly (no fallback)."""
from __future__ import annotations

import importlib.util

import pytest

from fixer4d.errors import BackendUnavailable
from fixer4d.restore.base import Restorer
from fixer4d.restore.cogvideo import WEIGHTS_ENV, CogVideoConfig, CogVideoV2VRestorer

from .conftest import tiny_request

HAVE_DIFFUSERS = importlib.util.find_spec("diffusers") is not None


def test_is_a_restorer():
    assert isinstance(CogVideoV2VRestorer(), Restorer)
    assert CogVideoV2VRestorer(CogVideoConfig(strength=0.3)).settings()["strength"] == 0.3


def test_missing_everything_is_named(monkeypatch):
    monkeypatch.delenv(WEIGHTS_ENV, raising=False)
    restorer = CogVideoV2VRestorer(CogVideoConfig(device="cuda"))
    with pytest.raises(BackendUnavailable) as info:
        restorer.restore(tiny_request())
    message = str(info.value)
    assert WEIGHTS_ENV in message
    if not HAVE_DIFFUSERS:
        assert "diffusers" in message
    import torch

    if not torch.cuda.is_available():
        assert "CUDA" in message


def test_weights_directory_is_checked(tmp_path, monkeypatch):
    monkeypatch.setenv(WEIGHTS_ENV, str(tmp_path / "nowhere"))
    assert "no model_index.json" in CogVideoV2VRestorer().unavailable_reason()
    (tmp_path / "model_index.json").write_text("{}")
    monkeypatch.setenv(WEIGHTS_ENV, str(tmp_path))
    reason = CogVideoV2VRestorer().unavailable_reason()
    assert reason is None or "weights" not in reason
