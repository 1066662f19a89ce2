"""The colour a render shows where no Gaussian covers a pixel (``training.background``).

Four cameras leave parts of every far view unseen: no Gaussian lies there, and a render shows
the background colour. Over black, such a region is as wrong as it can be in a lit room; over
the train views' mean colour it is the least-squares guess that knows nothing of the region. The
model trains over the same colour, so a train view's dark parts are dark Gaussians rather than
holes that let the background through (docs/decisions/background.md).

``training.background`` is three numbers in [0, 1], or ``"mean"`` (the default): the mean RGB of
the scene's train views, resolved wherever a training or a render needs it from that scene's own
train cameras (the self-check's fold from its fold cameras: its held-back camera adds nothing).
"""
from __future__ import annotations

import weakref
from typing import Any

import numpy as np

from fixer4d.errors import InputError

MEAN = "mean"
BACKGROUNDS = (MEAN,)
# Frames per train camera that enter the mean, evenly spread over the clip: the mean colour of a
# room moves little within a clip, and a long capture need not decode every frame for it.
MEAN_FRAMES = 16
# Resolved means per scene object (a scene is read once however many renders ask).
_resolved: "weakref.WeakKeyDictionary[Any, tuple[float, float, float]]" = weakref.WeakKeyDictionary()


def check_background(value: Any) -> tuple[float, float, float] | str:
    """``value`` as a TrainingConfig stores it: ``"mean"`` or a tuple of 3 floats in [0, 1];
    InputError otherwise."""
    if isinstance(value, str):
        if value not in BACKGROUNDS:
            raise InputError(f"training.background {value!r}: give 3 numbers in [0, 1] or one of {list(BACKGROUNDS)}")
        return value
    try:
        rgb = tuple(float(x) for x in value)
    except (TypeError, ValueError):
        raise InputError(f"training.background {value!r}: give 3 numbers in [0, 1] or {MEAN!r}") from None
    if len(rgb) != 3 or not all(0.0 <= x <= 1.0 for x in rgb):
        raise InputError(f"training.background {value!r}: give 3 numbers in [0, 1] or {MEAN!r}")
    return rgb  # type: ignore[return-value]


def train_views_mean(scene) -> tuple[float, float, float]:
    """Mean RGB of ``scene``'s train cameras over up to MEAN_FRAMES frames each, rounded to 1e-6.

    Each image is summed in float64. For 8-bit frames that sum is exact (a pixel k/255 in float32
    is a multiple of 2^-32, an image's sum below 2^48 of those units), so the mean does not depend
    on the order of the additions: the same digits on every CPU; the rounding covers the rest."""
    if not scene.train_ids:
        raise InputError(f"{scene.name}: no train cameras to take the background colour from")
    from fixer4d.calib.sfm import spread_frames

    frames = spread_frames(scene.num_frames, MEAN_FRAMES)
    total, count = np.zeros(3), 0
    for cam in scene.train_ids:
        for f in frames:
            image = np.asarray(scene.frame(f, cam))
            total += image.reshape(-1, 3).astype(np.float64).sum(axis=0)
            count += image.shape[0] * image.shape[1]
    return tuple(round(float(x), 6) for x in np.clip(total / count, 0.0, 1.0))  # type: ignore[return-value]


def resolve_background(value: tuple[float, float, float] | str, scene) -> tuple[float, float, float]:
    """The RGB a render of ``scene`` uses for ``training.background`` ``value``."""
    value = check_background(value)
    if not isinstance(value, str):
        return value
    try:
        return _resolved[scene]
    except (KeyError, TypeError):
        pass
    rgb = train_views_mean(scene)
    try:
        _resolved[scene] = rgb
    except TypeError:  # a scene that cannot be weakly referenced is read again next time
        pass
    return rgb


__all__ = ["BACKGROUNDS", "MEAN", "MEAN_FRAMES", "check_background", "resolve_background", "train_views_mean"]
