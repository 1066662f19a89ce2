"""CogVideoV2VRestorer against a fake diffusers: the pipeline is loaded from the local weights
only, called with the clip as diffusers' CogVideoXVideoToVideoPipeline documents it (a list of
PIL frames, 8k + 1 of them, at a multiple of 16 pixels; ``output_type="np"``), and its output
(``frames``: (batch, frames, h, w, 3) float32 in [0, 1]) comes back as a RestoreResult of the
request's size with the real references at the endpoints. No CUDA tensor is made."""
from __future__ import annotations

import dataclasses
import sys
import types

import numpy as np
import pytest
import torch
from PIL import Image

from fixer4d.errors import BackendUnavailable
from fixer4d.restore.cogvideo import (CLIP_FRAME_MULTIPLE, GENERATED_CONFIDENCE, WEIGHTS_ENV, CogVideoConfig,
                                      CogVideoV2VRestorer)

from .conftest import tiny_request

# A generation size (width, height) that is not a multiple of the 16-pixel latent patch, and the
# size the adapter rounds it down to.
CONFIG_SIZE = (70, 50)
GENERATED_SIZE = (64, 48)


# Value of the fake pipeline's output frame k: a constant image per frame, so the frame order
# and the resize back are both visible in the result.
def _generated_value(k: int) -> float:
    return 0.1 * (k + 1)


class FakeGenerator:
    """Stands in for torch.Generator: records the device and the seed, allocates nothing."""

    def __init__(self, device: str = "cpu") -> None:
        self.device = device
        self.seed: int | None = None

    def manual_seed(self, seed: int) -> "FakeGenerator":
        self.seed = int(seed)
        return self


class FakePipeline:
    """CogVideoXVideoToVideoPipeline as diffusers documents it: ``from_pretrained(path, torch_dtype=,
    local_files_only=)``, ``.to(device)``, ``__call__(video=[PIL images], prompt=, ...,
    callback_on_step_end=)`` -> an object whose ``frames`` is (1, F, h, w, 3) float32 for
    ``output_type="np"``; ``num_timesteps`` is int(steps x strength), the steps it denoises."""

    loads: list[tuple[tuple, dict]] = []
    instances: list["FakePipeline"] = []

    def __init__(self) -> None:
        self.device: str | None = None
        self.calls: list[dict] = []
        self.num_timesteps = 0
        FakePipeline.instances.append(self)

    @classmethod
    def from_pretrained(cls, *args, **kwargs) -> "FakePipeline":
        cls.loads.append((args, kwargs))
        return cls()

    def to(self, device: str) -> "FakePipeline":
        self.device = device
        return self

    def __call__(self, *, video, height, width, num_inference_steps, strength, output_type, callback_on_step_end,
                 **kwargs):
        self.calls.append(dict(video=video, height=height, width=width, num_inference_steps=num_inference_steps,
                               strength=strength, output_type=output_type, **kwargs))
        self.num_timesteps = min(int(num_inference_steps * strength), num_inference_steps)
        for i in range(self.num_timesteps):
            assert callback_on_step_end(self, i, 1000 - i, {}) == {}
        frames = np.stack([np.full((height, width, 3), _generated_value(k), np.float32) for k in range(len(video))])
        return types.SimpleNamespace(frames=frames[None])


@pytest.fixture
def fake_diffusers(monkeypatch):
    """diffusers with the fake pipeline, a CUDA device that is "available", a recording torch.Generator."""
    FakePipeline.loads = []
    FakePipeline.instances = []
    module = types.ModuleType("diffusers")
    module.CogVideoXVideoToVideoPipeline = FakePipeline
    monkeypatch.setitem(sys.modules, "diffusers", module)
    monkeypatch.setattr(torch.cuda, "is_available", lambda: True)
    monkeypatch.setattr(torch, "Generator", FakeGenerator)
    monkeypatch.delenv(WEIGHTS_ENV, raising=False)
    return FakePipeline


@pytest.fixture
def weights(tmp_path):
    (tmp_path / "model_index.json").write_text("{}")
    return tmp_path


# Reference images of the clip's endpoints: constant, so that they are recognizable after any resize.
REFERENCE_VALUES = (0.25, 0.75)


def _request(frames: int = 3):
    """A smooth clip (a horizontal ramp) whose endpoints are the reference cameras, with constant
    reference images."""
    req = tiny_request(frames=frames, width=32, height=24)
    ramp = np.broadcast_to(np.linspace(0.0, 1.0, 32, dtype=np.float32)[None, :, None], (frames, 24, 32, 3))
    refs = [np.full((24, 32, 3), v, np.float32) for v in REFERENCE_VALUES]
    return dataclasses.replace(req, rgb=ramp.copy(), ref_images=refs)


def _config(weights, **overrides) -> CogVideoConfig:
    return CogVideoConfig(weights=str(weights), width=CONFIG_SIZE[0], height=CONFIG_SIZE[1], dtype="float16",
                          device="cuda", strength=0.5, num_inference_steps=10, guidance_scale=4.0, seed=7,
                          prompt="p", negative_prompt="n", **overrides)


def test_pipeline_is_loaded_from_the_local_weights_once(fake_diffusers, weights):
    restorer = CogVideoV2VRestorer(_config(weights))
    restorer.restore(_request())
    restorer.restore(_request())
    assert fake_diffusers.loads == [((str(weights),), {"torch_dtype": torch.float16, "local_files_only": True})]
    (pipe,) = fake_diffusers.instances
    assert pipe.device == "cuda" and len(pipe.calls) == 2


def test_call_follows_the_documented_arguments(fake_diffusers, weights):
    request = _request(frames=3)
    CogVideoV2VRestorer(_config(weights)).restore(request)
    (call,) = fake_diffusers.instances[0].calls
    video = call.pop("video")
    generator = call.pop("generator")
    assert call == {"height": GENERATED_SIZE[1], "width": GENERATED_SIZE[0], "num_inference_steps": 10,
                    "strength": 0.5, "output_type": "np", "prompt": "p", "negative_prompt": "n",
                    "guidance_scale": 4.0}
    assert isinstance(generator, FakeGenerator) and generator.device == "cuda" and generator.seed == 7
    # 8k + 1 frames (an odd number of latent frames), the clip's last frame repeated to fill them
    assert len(video) == CLIP_FRAME_MULTIPLE + 1
    assert all(isinstance(f, Image.Image) and f.mode == "RGB" and f.size == GENERATED_SIZE for f in video)
    pixels = np.stack([np.asarray(f) for f in video])
    assert pixels.dtype == np.uint8
    assert all(np.array_equal(pixels[k], pixels[2]) for k in range(3, len(video)))
    # the endpoints are the real reference images, the middle frame the render (a ramp over [0, 255])
    for k, value in ((0, REFERENCE_VALUES[0]), (2, REFERENCE_VALUES[1])):
        assert np.all(pixels[k] == round(value * 255))
    ramp = pixels[1].astype(np.float32).mean(axis=(0, 2))
    assert ramp[0] < 8 and ramp[-1] > 247 and np.all(np.diff(ramp) >= 0)


def test_output_comes_back_at_the_request_size(fake_diffusers, weights):
    request = _request(frames=3)
    result = CogVideoV2VRestorer(_config(weights)).restore(request)
    F, H, W = request.num_frames, request.height, request.width
    assert result.rgb.shape == (F, H, W, 3) and result.rgb.dtype == np.float32
    assert result.confidence.shape == (F, H, W) and result.confidence.dtype == np.float32
    assert 0.0 <= result.rgb.min() and result.rgb.max() <= 1.0
    # generated frame k restores clip frame k (constant frames survive the resize exactly)
    np.testing.assert_allclose(result.rgb[1], _generated_value(1), rtol=1e-6)
    assert np.all(result.confidence[1] == GENERATED_CONFIDENCE)
    # endpoints at the reference cameras: the real images, full confidence
    for k, value in ((0, REFERENCE_VALUES[0]), (F - 1, REFERENCE_VALUES[1])):
        assert np.all(result.rgb[k] == np.float32(value)) and np.all(result.confidence[k] == 1.0)
    np.testing.assert_allclose(result.frame_confidence, result.confidence.reshape(F, -1).mean(axis=1))


def test_generated_values_are_clipped(fake_diffusers, weights, monkeypatch):
    monkeypatch.setitem(globals(), "_generated_value", lambda k: 1.5 if k % 2 else -0.5)
    result = CogVideoV2VRestorer(_config(weights)).restore(_request(frames=3))
    assert np.all(result.rgb[1] == 1.0)


def test_progress_reaches_one_over_the_denoised_steps(fake_diffusers, weights):
    seen: list[float] = []
    CogVideoV2VRestorer(_config(weights)).restore(_request(), progress=seen.append)
    steps = fake_diffusers.instances[0].num_timesteps
    assert steps == 5  # 10 steps at strength 0.5
    assert seen == pytest.approx([(i + 1) / steps for i in range(steps)])


def test_missing_weights_folder_is_named(fake_diffusers, tmp_path):
    absent = tmp_path / "no_weights_here"
    restorer = CogVideoV2VRestorer(_config(absent))
    with pytest.raises(BackendUnavailable) as info:
        restorer.restore(_request())
    message = str(info.value)
    assert str(absent) in message and "model_index.json" in message
    assert "diffusers package" not in message and "CUDA" not in message  # both present here
    assert fake_diffusers.loads == []


def test_missing_cuda_is_named(fake_diffusers, weights, monkeypatch):
    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    with pytest.raises(BackendUnavailable, match="CUDA") as info:
        CogVideoV2VRestorer(_config(weights)).restore(_request())
    assert "weights" not in str(info.value)
    assert fake_diffusers.loads == []
