"""Where the cameras do not determine the scene: the disagreement of two fields' renders.

Two spacetime-Gaussian fields trained from the same initialization with different seeds
(densification draws, view and frame order; ``fixer4d.train.co_fields``) agree wherever the train
cameras pin the scene down, and drift apart where they do not (CoR-GS, ECCV 2024). At one camera
and time the per-pixel disagreement of their renders is therefore a measured "undetermined"
weight, beside the geometric ``restore.visibility.unobserved_weight`` (a depth test with an angle
ramp) that needs no second field.

Rule, per pixel p (colours in [0, 1], composited over the same background):
1. colour = mean over RGB of |rgb_a - rgb_b|; coverage = |alpha_a - alpha_b|;
2. each is averaged over a ``window`` x ``window`` box, so one stray pixel (a single splat's edge,
   resampling noise) cannot count;
3. each smoothed difference goes through a linear ramp: 0 up to its noise floor, 1 from its
   "different surface" level (``*_LOW`` / ``*_HIGH`` below);
4. undetermined = max(colour ramp, coverage ramp).

Two identical renders give exactly zero everywhere (every difference is 0, below every floor).
"""
from __future__ import annotations

import cv2
import numpy as np

from fixer4d.errors import InputError

# Side (pixels) of the box the differences are averaged over: one pixel of even the largest
# difference (1.0) averages to 1/25 = 0.04 over 5x5, below both noise floors, so isolated pixels
# never count while a disagreeing region 3 pixels wide (9/25 of the window) reaches the ramps.
WINDOW_PX = 5
# Colour (mean absolute RGB difference, [0, 1]): two renders of the same surface by two seeds
# differ by resampling and fitting noise of ~0.02 (the restorers' warp-agreement noise,
# restore/constants.py AGREEMENT_SIGMA's reasoning); 0.1 means they show different surfaces or
# textures (that constant's "different surface" level): the ramp is centred there (half weight at
# 0.1) and its floor sits above the noise with margin.
COLOUR_LOW = 0.05
COLOUR_HIGH = 0.15
# Coverage (|alpha_a - alpha_b|): soft edges of the same silhouette differ by a few hundredths;
# a difference of half the opacity range is one field rendering a surface the other lacks (the
# hole ramp of restore/visibility.py spans 0.2..0.8 alpha, a width of 0.6).
COVERAGE_LOW = 0.1
COVERAGE_HIGH = 0.5


def _ramp(x: np.ndarray, low: float, high: float) -> np.ndarray:
    return np.clip((x - low) / (high - low), 0.0, 1.0)


def _box(x: np.ndarray, window: int) -> np.ndarray:
    return cv2.blur(x.astype(np.float32), (window, window), borderType=cv2.BORDER_REFLECT)


def undetermined_map(rgb_a: np.ndarray, rgb_b: np.ndarray, alpha_a: np.ndarray, alpha_b: np.ndarray, *,
                     window: int = WINDOW_PX, colour_low: float = COLOUR_LOW, colour_high: float = COLOUR_HIGH,
                     coverage_low: float = COVERAGE_LOW, coverage_high: float = COVERAGE_HIGH) -> np.ndarray:
    """(H, W) float32 in [0, 1]: how much two fields' renders at one camera and time disagree
    (1 = the train cameras do not determine this pixel; see the module docstring).

    rgb_a, rgb_b: (H, W, 3) colour in [0, 1] of field A and field B, composited over the same
    background (numpy, or anything ``np.asarray`` takes, e.g. a CPU torch tensor).
    alpha_a, alpha_b: (H, W) accumulated opacity in [0, 1] of the same renders.
    window: odd side in pixels of the smoothing box. *_low / *_high: the ramps' ends, in the units
    of a mean absolute RGB difference and of an alpha difference.
    NaNs count as 0 (a render that produced none has none of its own colour there).
    """
    a = np.nan_to_num(np.asarray(rgb_a, np.float32), nan=0.0)
    b = np.nan_to_num(np.asarray(rgb_b, np.float32), nan=0.0)
    aa = np.nan_to_num(np.asarray(alpha_a, np.float32), nan=0.0)
    ab = np.nan_to_num(np.asarray(alpha_b, np.float32), nan=0.0)
    if a.ndim != 3 or a.shape[2] != 3 or b.shape != a.shape or aa.shape != a.shape[:2] or ab.shape != aa.shape:
        raise InputError(f"undetermined_map: need rgb (H, W, 3) twice and alpha (H, W) twice, got {a.shape}, "
                         f"{b.shape}, {aa.shape}, {ab.shape}")
    if window < 1 or window % 2 == 0:
        raise InputError(f"undetermined_map: window must be an odd number of pixels >= 1, got {window}")
    if not (0.0 <= colour_low < colour_high and 0.0 <= coverage_low < coverage_high):
        raise InputError("undetermined_map: need 0 <= low < high for the colour and coverage ramps")
    colour = _box(np.abs(a - b).mean(axis=2), window)
    coverage = _box(np.abs(np.clip(aa, 0.0, 1.0) - np.clip(ab, 0.0, 1.0)), window)
    out = np.maximum(_ramp(colour, colour_low, colour_high), _ramp(coverage, coverage_low, coverage_high))
    return out.astype(np.float32)


def combined_weight(visibility: np.ndarray, undetermined: np.ndarray, mode: str) -> np.ndarray:
    """The per-pixel weight that gates restoration and the pseudo-loss, (...) float32 in [0, 1]:
    ``mode`` "visibility" -> the visibility weight (``restore.visibility``), "undetermined" -> the
    two fields' disagreement (``undetermined_map``), "max" -> the larger of the two. Both (...)."""
    if mode == "visibility":
        return np.asarray(visibility, np.float32)
    if mode == "undetermined":
        return np.asarray(undetermined, np.float32)
    if mode == "max":
        return np.maximum(visibility, undetermined).astype(np.float32)
    raise InputError(f"combined_weight: mode must be visibility, undetermined or max, got {mode!r}")


__all__ = ["undetermined_map", "combined_weight", "WINDOW_PX", "COLOUR_LOW", "COLOUR_HIGH", "COVERAGE_LOW", "COVERAGE_HIGH"]
