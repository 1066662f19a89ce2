"""CogVideoV2VRestorer through diffusers' real CogVideoXVideoToVideoPipeline, with no weights to
download: the test builds a tiny, randomly initialised pipeline from the real classes (CogVideoX
transformer and VAE, a T5 encoder, a T5 tokenizer with a local vocabulary, CogVideoX's DDIM
scheduler), saves it to a folder, and the restorer loads it from there with ``local_files_only``.
So the loading arguments, the dtype, the call's arguments, the callback protocol and the number
of frames the VAE gives back are those of the installed diffusers and transformers, not of the
fake in test_cogvideo_adapter.py. The generated pixels are noise from random weights: only their
form, where they go in the clip, and their repeatability are checked.

Runs on CUDA in bfloat16 when there is a GPU, else on the CPU in float32 (a few seconds). Skipped
when diffusers or transformers is not installed; neither is a dependency of fixer4d.
"""
from __future__ import annotations

import cv2
import numpy as np
import pytest
import torch

pytest.importorskip("transformers", minversion="5.0",
                    reason="needs transformers >= 5 (pip install diffusers transformers) for the real CogVideoX "
                           "pipeline")
pytest.importorskip("diffusers", reason="needs diffusers (pip install diffusers transformers) for the real "
                                        "CogVideoX pipeline")

from diffusers import (AutoencoderKLCogVideoX, CogVideoXDDIMScheduler, CogVideoXTransformer3DModel,  # noqa: E402
                       CogVideoXVideoToVideoPipeline)
from transformers import T5Config, T5EncoderModel, T5Tokenizer  # noqa: E402

from fixer4d.restore.base import RestoreRequest  # noqa: E402
from fixer4d.restore.cogvideo import (CLIP_FRAME_MULTIPLE, GENERATED_CONFIDENCE, CogVideoConfig,  # noqa: E402
                                      CogVideoV2VRestorer)

from .conftest import tiny_request  # noqa: E402

# The restorer's device and dtype: bfloat16 is what a GPU run uses; the CPU computes in float32
# (bfloat16 there is slow and not what any real run would choose).
DEVICE = "cuda" if torch.cuda.is_available() else "cpu"
DTYPE = "bfloat16" if DEVICE == "cuda" else "float32"
# Clip length: the restorer pads it to 8k + 1 = 9 frames (3 latent frames), so the padding and
# the frame-for-frame mapping of the output back onto the clip are both exercised.
FRAMES = 5
# Clip size (width, height): not the generation size, so the resize to it and back is exercised.
CLIP_SIZE = (40, 30)
# Reference images at twice the clip's resolution (a real frame is larger than the render), so
# the endpoints are the references resized as the restorer resizes them.
REFERENCE_SIZE = (80, 60)
# Generation size (width, height): the smallest multiples of 16 (8x VAE, 2x2 patches) that give a
# patch grid of more than one cell, and width != height so a swapped pair would fail.
GENERATION_SIZE = (48, 32)
# Scheduler steps, and the share of them that video-to-video denoises: 2 of 4, so progress must
# count the denoised steps (the pipeline's num_timesteps), not num_inference_steps.
STEPS = 4
STRENGTH = 0.5
# Seed of the restorer's generator, and of the random weights of the tiny pipeline.
SEED = 3
WEIGHTS_SEED = 0
# Text width shared by the T5 encoder (d_model) and the transformer's text projection.
TEXT_DIM = 32
# Words of the restorer's default prompts as whole pieces, letters for anything else, so every
# prompt tokenizes without a download.
PROMPT_WORDS = "a sharp detailed artifact free video of the same scene blurry holes artifacts distorted"


def _tokenizer() -> T5Tokenizer:
    """A T5 (Unigram) tokenizer over a small local vocabulary: pad, eos, unk first as T5's."""
    vocab = [("<pad>", 0.0), ("</s>", 0.0), ("<unk>", 0.0), ("\u2581", -2.0)]
    vocab += [(c, -5.0) for c in "abcdefghijklmnopqrstuvwxyz,-"]
    vocab += [("\u2581" + w, -1.0) for w in dict.fromkeys(PROMPT_WORDS.split())]
    return T5Tokenizer(vocab=vocab, extra_ids=0)


def _tiny_pipeline() -> CogVideoXVideoToVideoPipeline:
    """The real pipeline classes at toy sizes, random weights drawn from WEIGHTS_SEED."""
    tokenizer = _tokenizer()
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(WEIGHTS_SEED)
        text_encoder = T5EncoderModel(T5Config(vocab_size=len(tokenizer), d_model=TEXT_DIM, d_kv=8, d_ff=32,
                                               num_layers=1, num_heads=2, relative_attention_num_buckets=8))
        # CogVideoX 1.0 layout (no temporal patches); 2 heads x 16 channels: the 3D sin-cos
        # position embedding needs a width divisible by 16. The restorer leaves the pipeline's
        # default of 226 text tokens, so the transformer is built for that text length.
        transformer = CogVideoXTransformer3DModel(
            num_attention_heads=2, attention_head_dim=16, in_channels=4, out_channels=4, time_embed_dim=4,
            text_embed_dim=TEXT_DIM, num_layers=1, sample_width=GENERATION_SIZE[0] // 8,
            sample_height=GENERATION_SIZE[1] // 8, sample_frames=CLIP_FRAME_MULTIPLE + 1, patch_size=2,
            temporal_compression_ratio=4, max_text_seq_length=226)
        # four blocks as in CogVideoX: 8x spatial and 4x temporal compression; 8 channels in 2 groups
        vae = AutoencoderKLCogVideoX(block_out_channels=(8, 8, 8, 8), latent_channels=4, layers_per_block=1,
                                     norm_num_groups=2, temporal_compression_ratio=4,
                                     sample_width=GENERATION_SIZE[0], sample_height=GENERATION_SIZE[1])
    # the scheduler settings of the CogVideoX-2b checkpoint
    scheduler = CogVideoXDDIMScheduler(prediction_type="v_prediction", rescale_betas_zero_snr=True,
                                       clip_sample=False, timestep_spacing="trailing")
    return CogVideoXVideoToVideoPipeline(tokenizer=tokenizer, text_encoder=text_encoder, vae=vae,
                                         transformer=transformer, scheduler=scheduler)


@pytest.fixture(scope="module")
def weights(tmp_path_factory):
    """A pipeline directory (model_index.json and one folder per component) as from_pretrained reads it."""
    path = tmp_path_factory.mktemp("tiny_cogvideox")
    _tiny_pipeline().save_pretrained(str(path))
    return path


def _config(weights, seed: int = SEED) -> CogVideoConfig:
    return CogVideoConfig(weights=str(weights), device=DEVICE, dtype=DTYPE, width=GENERATION_SIZE[0],
                          height=GENERATION_SIZE[1], num_inference_steps=STEPS, strength=STRENGTH, seed=seed)


def _request() -> RestoreRequest:
    """A random clip whose endpoints are the reference cameras, references at REFERENCE_SIZE."""
    req = tiny_request(frames=FRAMES, width=CLIP_SIZE[0], height=CLIP_SIZE[1])
    rng = np.random.default_rng(1)
    w, h = REFERENCE_SIZE
    return RestoreRequest(
        rgb=req.rgb, depth=req.depth, alpha=req.alpha, cameras=req.cameras, time=req.time, frame=req.frame,
        ref_images=[rng.random((h, w, 3), dtype=np.float32) for _ in range(2)],
        ref_cameras=[cam.resized(w, h) for cam in req.ref_cameras],
        ref_depths=[np.full((h, w), 4.0, np.float32)] * 2, ref_alphas=[np.ones((h, w), np.float32)] * 2,
        trajectory=req.trajectory)


class Recorder:
    """Counts CogVideoXVideoToVideoPipeline.from_pretrained calls and keeps, per pipeline call, the
    number of frames that went in and the frames that came out (the pipeline's own video processor)."""

    def __init__(self, monkeypatch: pytest.MonkeyPatch) -> None:
        self.loads: list[tuple] = []
        self.pipelines: list[CogVideoXVideoToVideoPipeline] = []
        self.frames_in: list[int] = []
        self.frames_out: list[np.ndarray] = []
        original = CogVideoXVideoToVideoPipeline.from_pretrained

        def from_pretrained(cls, *args, **kwargs):
            self.loads.append((args, kwargs))
            pipe = original(*args, **kwargs)
            preprocess, postprocess = pipe.video_processor.preprocess_video, pipe.video_processor.postprocess_video

            def preprocess_video(video, *a, **k):
                self.frames_in.append(len(video))
                return preprocess(video, *a, **k)

            def postprocess_video(*a, **k):
                out = postprocess(*a, **k)
                self.frames_out.append(np.asarray(out))
                return out

            pipe.video_processor.preprocess_video = preprocess_video
            pipe.video_processor.postprocess_video = postprocess_video
            self.pipelines.append(pipe)
            return pipe

        monkeypatch.setattr(CogVideoXVideoToVideoPipeline, "from_pretrained", classmethod(from_pretrained))


@pytest.fixture(scope="module")
def two_runs(weights):
    """One restorer, two restore calls of the same request (progress recorded on the first)."""
    with pytest.MonkeyPatch.context() as monkeypatch:
        recorder = Recorder(monkeypatch)
        restorer = CogVideoV2VRestorer(_config(weights))
        request = _request()
        progress: list[float] = []
        first = restorer.restore(request, progress=progress.append)
        second = restorer.restore(request)
    return request, first, second, progress, recorder


def test_restorer_is_available_with_the_tiny_weights(weights):
    assert CogVideoV2VRestorer(_config(weights)).unavailable_reason() is None


def test_pipeline_is_loaded_once_from_the_local_folder(two_runs, weights):
    _, _, _, _, recorder = two_runs
    assert len(recorder.loads) == 1
    (args, kwargs), = recorder.loads
    assert args == (str(weights),) and kwargs["local_files_only"] is True
    (pipe,) = recorder.pipelines
    assert pipe.device.type == DEVICE
    assert pipe.transformer.dtype == pipe.vae.dtype == pipe.text_encoder.dtype == getattr(torch, DTYPE)
    assert len(recorder.frames_out) == 2


def test_pipeline_gives_back_as_many_frames_as_it_gets(two_runs):
    _, _, _, _, recorder = two_runs
    n_in = recorder.frames_in[0]
    assert n_in == CLIP_FRAME_MULTIPLE + 1  # FRAMES padded to 8k + 1
    raw = recorder.frames_out[0]
    assert raw.shape == (1, n_in, GENERATION_SIZE[1], GENERATION_SIZE[0], 3) and raw.dtype == np.float32
    assert np.isfinite(raw).all() and raw.min() >= 0.0 and raw.max() <= 1.0


def test_result_has_the_request_shape_and_range(two_runs):
    request, result, _, _, _ = two_runs
    F, H, W = request.num_frames, request.height, request.width
    assert result.rgb.shape == (F, H, W, 3) and result.rgb.dtype == np.float32
    assert result.confidence.shape == (F, H, W) and result.frame_confidence.shape == (F,)
    assert np.isfinite(result.rgb).all() and result.rgb.min() >= 0.0 and result.rgb.max() <= 1.0


def test_endpoints_are_the_references_and_the_rest_is_generated(two_runs):
    request, result, _, _, recorder = two_runs
    F, H, W = request.num_frames, request.height, request.width
    for k, ref in ((0, 0), (F - 1, 1)):
        expected = np.clip(cv2.resize(request.ref_images[ref], (W, H), interpolation=cv2.INTER_AREA), 0.0, 1.0)
        np.testing.assert_array_equal(result.rgb[k], expected)
        assert np.all(result.confidence[k] == 1.0)
    # generated frame k restores clip frame k: the pipeline's output, resized back to the clip
    generated = recorder.frames_out[0][0]
    for k in range(1, F - 1):
        expected = np.clip(cv2.resize(generated[k], (W, H), interpolation=cv2.INTER_AREA), 0.0, 1.0)
        np.testing.assert_array_equal(result.rgb[k], expected)
        assert np.all(result.confidence[k] == GENERATED_CONFIDENCE)
    np.testing.assert_allclose(result.frame_confidence, result.confidence.reshape(F, -1).mean(axis=1))


def test_progress_counts_the_denoised_steps_up_to_one(two_runs):
    _, _, _, progress, recorder = two_runs
    denoised = int(recorder.pipelines[0].num_timesteps)
    assert denoised == int(STEPS * STRENGTH)
    assert progress == pytest.approx([(i + 1) / denoised for i in range(denoised)])
    assert progress[-1] == 1.0


@pytest.mark.skipif(DEVICE != "cpu", reason="bitwise repeatability is asserted for CPU kernels only")
def test_same_seed_gives_the_same_clip(two_runs):
    _, first, second, _, _ = two_runs
    np.testing.assert_array_equal(first.rgb, second.rgb)
    np.testing.assert_array_equal(first.confidence, second.confidence)


def test_seed_reaches_the_pipeline(two_runs, weights):
    request, first, _, _, _ = two_runs
    other = CogVideoV2VRestorer(_config(weights, seed=SEED + 1)).restore(request)
    F = request.num_frames
    assert np.abs(other.rgb[1:F - 1] - first.rgb[1:F - 1]).max() > 1e-3
    np.testing.assert_array_equal(other.rgb[[0, F - 1]], first.rgb[[0, F - 1]])
