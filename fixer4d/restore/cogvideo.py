"""CogVideoV2VRestorer: an optional video diffusion restorer (CogVideoX video-to-video, diffusers).

Runs diffusers' ``CogVideoXVideoToVideoPipeline`` from LOCAL weights (a directory holding the
pipeline's ``model_index.json``, given in the config or by the environment variable
``FIXER4D_COGVIDEO_WEIGHTS``) on a CUDA device. The clip is conditioned on the real endpoint
references the way the pair trajectories allow: the trajectory's first and last cameras are the
reference cameras, so those two input frames are replaced by the real images before denoising,
and the real images are put back in the output.

diffusers is imported lazily; when it, the weights or CUDA are missing, ``restore`` raises
``BackendUnavailable`` naming everything that is missing. There is no fallback: use
``ReferenceWarpRestorer`` on machines without them.
"""
from __future__ import annotations

import dataclasses
import os
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from fixer4d.errors import BackendUnavailable
from fixer4d.restore.base import ProgressFn, RestoreRequest, RestoreResult

WEIGHTS_ENV = "FIXER4D_COGVIDEO_WEIGHTS"
# CogVideoX's VAE compresses time by 4: clips of 4k + 1 frames map to k + 1 latent frames.
TEMPORAL_COMPRESSION = 4
# diffusers' CogVideoX VAE decodes latent frames two at a time after a first group of three, and an
# even number of latent frames comes back as 4 (k + 1) frames (the first latent frame repeated, the
# clip shifted by 3): only an odd number of latent frames, i.e. 8k + 1 input frames, decodes back
# frame for frame, so clips are padded to a multiple of this plus one.
CLIP_FRAME_MULTIPLE = 2 * TEMPORAL_COMPRESSION
# The transformer works on 16x16-pixel latent patches (VAE x8, patch x2): sizes must be multiples.
SPATIAL_MULTIPLE = 16
# An endpoint camera is the reference camera when their centres are this close relative to the
# reference baseline (trajectory endpoints are the reference poses up to float round-off).
ENDPOINT_REL_TOL = 1e-6
# Per-pixel confidence given to generated pixels: a diffusion model's output is plausible but
# not an observation, so the trainer should weight it below real support (1 = the references).
GENERATED_CONFIDENCE = 0.5


@dataclass
class CogVideoConfig:
    """Settings of the CogVideoX V2V restorer. weights: local pipeline directory (None = $FIXER4D_COGVIDEO_WEIGHTS)."""

    weights: str | None = None
    prompt: str = "a sharp, detailed, artifact-free video of the same scene"
    negative_prompt: str = "blurry, holes, artifacts, distorted"
    strength: float = 0.6
    num_inference_steps: int = 30
    guidance_scale: float = 6.0
    width: int = 720
    height: int = 480
    dtype: str = "bfloat16"
    device: str = "cuda"
    seed: int = 0


class CogVideoV2VRestorer:
    """Reference-conditioned CogVideoX video-to-video restoration (see module doc)."""

    name = "cogvideox_v2v"

    def __init__(self, config: CogVideoConfig | None = None) -> None:
        self.config = config if config is not None else CogVideoConfig()
        self._pipe: Any = None
        self._lock = threading.Lock()

    def settings(self) -> dict[str, Any]:
        return dataclasses.asdict(self.config)

    def weights_path(self) -> Path | None:
        path = self.config.weights or os.environ.get(WEIGHTS_ENV)
        return Path(path).expanduser() if path else None

    def unavailable_reason(self) -> str | None:
        """Why this restorer cannot run here (everything missing), or None when it can."""
        missing = []
        try:
            import diffusers  # noqa: F401
        except ImportError:
            missing.append("the diffusers package (pip install diffusers transformers accelerate sentencepiece)")
        path = self.weights_path()
        if path is None:
            missing.append(f"local CogVideoX weights (set CogVideoConfig.weights or ${WEIGHTS_ENV} to the "
                           "pipeline directory holding model_index.json)")
        elif not (path / "model_index.json").is_file():
            missing.append(f"CogVideoX weights at {path} (no model_index.json there; download the pipeline, "
                           "e.g. THUDM/CogVideoX-2b, into that directory)")
        import torch

        if self.config.device.startswith("cuda") and not torch.cuda.is_available():
            missing.append("a CUDA device (torch.cuda.is_available() is False)")
        if not missing:
            return None
        return "CogVideoX restorer unavailable; missing: " + "; ".join(missing)

    def _pipeline(self) -> Any:
        with self._lock:
            if self._pipe is None:
                reason = self.unavailable_reason()
                if reason is not None:
                    raise BackendUnavailable(reason)
                import torch
                from diffusers import CogVideoXVideoToVideoPipeline

                # local_files_only: the weights directory is the whole source; never reach the Hub
                pipe = CogVideoXVideoToVideoPipeline.from_pretrained(
                    str(self.weights_path()), torch_dtype=getattr(torch, self.config.dtype), local_files_only=True)
                self._pipe = pipe.to(self.config.device)
            return self._pipe

    def restore(self, request: RestoreRequest, progress: ProgressFn | None = None) -> RestoreResult:
        """Denoise the clip (F, H, W, 3) at the configured size with the endpoints set to the references."""
        import torch
        from PIL import Image

        cfg = self.config
        pipe = self._pipeline()
        F, H, W = request.num_frames, request.height, request.width
        frames = np.clip(np.nan_to_num(request.rgb, nan=0.0), 0.0, 1.0).copy()
        fixed = self._endpoint_frames(request)
        for k, image in fixed.items():
            frames[k] = image
        n_in = CLIP_FRAME_MULTIPLE * int(np.ceil((F - 1) / CLIP_FRAME_MULTIPLE)) + 1
        order = list(range(F)) + [F - 1] * (n_in - F)
        w = max(SPATIAL_MULTIPLE, cfg.width // SPATIAL_MULTIPLE * SPATIAL_MULTIPLE)
        h = max(SPATIAL_MULTIPLE, cfg.height // SPATIAL_MULTIPLE * SPATIAL_MULTIPLE)
        video = [Image.fromarray(np.round(cv2.resize(frames[k], (w, h), interpolation=cv2.INTER_CUBIC)
                                          .clip(0, 1) * 255).astype(np.uint8)) for k in order]
        steps = max(1, cfg.num_inference_steps)

        def on_step(pipe_: Any, step: int, _timestep: Any, callback_kwargs: dict) -> dict:
            # the pipeline denoises only the last ``strength`` share of the steps (its num_timesteps)
            if progress is not None:
                progress(min(1.0, (step + 1) / max(1, int(pipe_.num_timesteps))))
            return callback_kwargs

        # a RestoreCancelled raised by ``progress`` (job cancellation) propagates out of the pipeline
        out = pipe(video=video, prompt=cfg.prompt, negative_prompt=cfg.negative_prompt, height=h, width=w,
                   num_inference_steps=steps, strength=cfg.strength, guidance_scale=cfg.guidance_scale,
                   generator=torch.Generator(device=cfg.device).manual_seed(cfg.seed), output_type="np",
                   callback_on_step_end=on_step)
        generated = np.asarray(out.frames[0], dtype=np.float32)
        rgb = np.empty_like(frames)
        confidence = np.full((F, H, W), GENERATED_CONFIDENCE, np.float32)
        for k in range(F):
            src = generated[min(k, len(generated) - 1)]
            rgb[k] = cv2.resize(src, (W, H), interpolation=cv2.INTER_AREA)
        for k, image in fixed.items():
            rgb[k] = image
            confidence[k] = 1.0
        return RestoreResult(np.clip(rgb, 0.0, 1.0), confidence, confidence.reshape(F, -1).mean(axis=1))

    @staticmethod
    def _endpoint_frames(request: RestoreRequest) -> dict[int, np.ndarray]:
        """{frame index: reference image resized to the clip} for endpoints that sit at a reference camera."""
        F, H, W = request.num_frames, request.height, request.width
        c0, c1 = request.ref_cameras[0].center, request.ref_cameras[1].center
        tol = ENDPOINT_REL_TOL * max(float(np.linalg.norm(c1 - c0)), 1.0)
        fixed = {}
        for k, ref in ((0, 0), (F - 1, 1)):
            cam, ref_cam = request.cameras[k], request.ref_cameras[ref]
            if np.linalg.norm(cam.center - ref_cam.center) <= tol and np.allclose(cam.R, ref_cam.R, atol=1e-6):
                fixed[k] = cv2.resize(request.ref_images[ref], (W, H), interpolation=cv2.INTER_AREA)
        return fixed
