"""The restorer protocol: a rendered clip along a trajectory in, a restored clip out.

Restorers never render (docs/design.md §11): the request carries the rendered clip (rgb, depth,
alpha) at every trajectory camera, the timestamp, the two real endpoint frames with their
cameras, and the model's depth and alpha rendered at those reference cameras. Optionally it also
carries the other real views of the same timestamp ("extra" views).

Arrays are numpy float32 at this boundary (torch tensors are accepted and converted); images are
RGB in [0, 1], depths are camera z-depths in world units (0, NaN or inf = unknown).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, Protocol, runtime_checkable

import numpy as np

from fixer4d.errors import InputError
from fixer4d.geometry.camera import Camera

ProgressFn = Callable[[float], None]


class RestoreCancelled(Exception):
    """Raised from a progress callback to stop a restorer between frames (see jobs.py)."""


def _as_array(value: Any, name: str) -> np.ndarray:
    """numpy float32 copy-free view of a numpy array or a (detached, CPU) torch tensor."""
    if hasattr(value, "detach"):
        value = value.detach().cpu().numpy()
    try:
        return np.asarray(value, dtype=np.float32)
    except (TypeError, ValueError) as exc:
        raise InputError(f"restore request: {name} is not a numeric array ({exc})") from exc


def _check_shape(arr: np.ndarray, shape: tuple[int, ...], name: str) -> None:
    if arr.shape != shape:
        raise InputError(f"restore request: {name} has shape {arr.shape}, expected {shape}; "
                         "render every array at the camera it belongs to")


@dataclass
class RestoreRequest:
    """One clip to restore.

    rgb: (F, H, W, 3) rendered colours. depth: (F, H, W) rendered expected z-depth (0 where
    nothing was rendered). alpha: (F, H, W) accumulated opacity in [0, 1]. cameras: F cameras of
    the trajectory (each H x W). time: the clip's timestamp t = f / T. frame: its frame index f.
    ref_images: 2 real frames (H_r, W_r, 3) at ref_cameras (the trajectory's endpoints).
    ref_depths / ref_alphas: 2 maps (H_r, W_r): the MODEL's depth and alpha rendered at the
    references (used for the occlusion test). extra_images / extra_cameras / extra_depths: the
    other real views of the same timestamp with the model's depth there, or None.
    trajectory: metadata (name, pair, amplitude, arc index, ...), JSON-serializable.
    unobserved: (F, H, W) in [0, 1] or None: how unobserved each clip pixel is by the train
    cameras (``restore.visibility``; 1 = no train camera explains it), computed from the model's
    renders only. Restorers may ignore it; the pipeline gates pseudo-targets by it.
    """

    rgb: np.ndarray
    depth: np.ndarray
    alpha: np.ndarray
    cameras: list[Camera]
    time: float
    frame: int
    ref_images: list[np.ndarray]
    ref_cameras: list[Camera]
    ref_depths: list[np.ndarray]
    ref_alphas: list[np.ndarray]
    extra_images: list[np.ndarray] | None = None
    extra_cameras: list[Camera] | None = None
    extra_depths: list[np.ndarray] | None = None
    trajectory: dict[str, Any] = field(default_factory=dict)
    unobserved: np.ndarray | None = None

    def __post_init__(self) -> None:
        self.rgb = _as_array(self.rgb, "rgb")
        if self.rgb.ndim != 4 or self.rgb.shape[-1] != 3 or self.rgb.shape[0] < 1:
            raise InputError(f"restore request: rgb must be (F, H, W, 3) with F >= 1, got {self.rgb.shape}")
        F, H, W, _ = self.rgb.shape
        self.depth = _as_array(self.depth, "depth")
        self.alpha = _as_array(self.alpha, "alpha")
        _check_shape(self.depth, (F, H, W), "depth")
        _check_shape(self.alpha, (F, H, W), "alpha")
        self.cameras = list(self.cameras)
        if len(self.cameras) != F:
            raise InputError(f"restore request: {len(self.cameras)} cameras for {F} frames; pass one camera per frame")
        for k, cam in enumerate(self.cameras):
            if (cam.height, cam.width) != (H, W):
                raise InputError(f"restore request: camera {k} ({cam.name!r}) is {cam.width}x{cam.height}, "
                                 f"the clip is {W}x{H}")
        self.time = float(self.time)
        self.frame = int(self.frame)
        if len(self.ref_cameras) != 2 or len(self.ref_images) != 2 or len(self.ref_depths) != 2 \
                or len(self.ref_alphas) != 2:
            raise InputError("restore request: exactly 2 references (images, cameras, depths, alphas) are needed, "
                             f"got {len(self.ref_images)} images, {len(self.ref_cameras)} cameras, "
                             f"{len(self.ref_depths)} depths, {len(self.ref_alphas)} alphas")
        self.ref_cameras = list(self.ref_cameras)
        self.ref_images = [_as_array(im, f"ref_images[{r}]") for r, im in enumerate(self.ref_images)]
        self.ref_depths = [_as_array(d, f"ref_depths[{r}]") for r, d in enumerate(self.ref_depths)]
        self.ref_alphas = [_as_array(a, f"ref_alphas[{r}]") for r, a in enumerate(self.ref_alphas)]
        for r, cam in enumerate(self.ref_cameras):
            _check_shape(self.ref_images[r], (cam.height, cam.width, 3), f"ref_images[{r}]")
            _check_shape(self.ref_depths[r], (cam.height, cam.width), f"ref_depths[{r}]")
            _check_shape(self.ref_alphas[r], (cam.height, cam.width), f"ref_alphas[{r}]")
        extras = (self.extra_images, self.extra_cameras, self.extra_depths)
        if any(e is not None for e in extras):
            if any(e is None for e in extras) or not (len(extras[0]) == len(extras[1]) == len(extras[2])):
                raise InputError("restore request: extra_images, extra_cameras and extra_depths must be given "
                                 "together with one entry per extra view")
            self.extra_cameras = list(self.extra_cameras)
            self.extra_images = [_as_array(im, f"extra_images[{e}]") for e, im in enumerate(self.extra_images)]
            self.extra_depths = [_as_array(d, f"extra_depths[{e}]") for e, d in enumerate(self.extra_depths)]
            for e, cam in enumerate(self.extra_cameras):
                _check_shape(self.extra_images[e], (cam.height, cam.width, 3), f"extra_images[{e}]")
                _check_shape(self.extra_depths[e], (cam.height, cam.width), f"extra_depths[{e}]")
        self.trajectory = dict(self.trajectory)
        if self.unobserved is not None:
            self.unobserved = _as_array(self.unobserved, "unobserved")
            _check_shape(self.unobserved, (F, H, W), "unobserved")

    @property
    def num_frames(self) -> int:
        return int(self.rgb.shape[0])

    @property
    def height(self) -> int:
        return int(self.rgb.shape[1])

    @property
    def width(self) -> int:
        return int(self.rgb.shape[2])

    @property
    def num_extra(self) -> int:
        return 0 if self.extra_cameras is None else len(self.extra_cameras)


@dataclass
class RestoreResult:
    """A restored clip.

    rgb: (F, H, W, 3) float32 in [0, 1]. confidence: (F, H, W) float32 in [0, 1], how much each
    pixel is supported by real observations (0 = guessed). frame_confidence: (F,) float32, a
    per-frame summary (the mean of ``confidence``).
    """

    rgb: np.ndarray
    confidence: np.ndarray
    frame_confidence: np.ndarray

    def __post_init__(self) -> None:
        self.rgb = _as_array(self.rgb, "result rgb")
        self.confidence = _as_array(self.confidence, "result confidence")
        self.frame_confidence = _as_array(self.frame_confidence, "result frame_confidence").reshape(-1)
        if self.rgb.ndim != 4 or self.rgb.shape[-1] != 3:
            raise InputError(f"restore result: rgb must be (F, H, W, 3), got {self.rgb.shape}")
        _check_shape(self.confidence, self.rgb.shape[:3], "result confidence")
        _check_shape(self.frame_confidence, self.rgb.shape[:1], "result frame_confidence")

    @property
    def num_frames(self) -> int:
        return int(self.rgb.shape[0])


def blend_with_render(render: np.ndarray, result: RestoreResult, weight: np.ndarray | None = None,
                      hole: np.ndarray | None = None) -> RestoreResult:
    """The restored clip where it is trusted, the render elsewhere.

    render: (F, H, W, 3) the rendered clip the restorer started from. weight: (F, H, W) in [0, 1]
    or None, where the restorer may act (e.g. ``request.unobserved``). hole: (F, H, W) in [0, 1]
    or None, where the render holds no content (``restore.visibility.hole_weight``). Per pixel
    g = max(hole, weight x confidence); rgb = render + g (restored - render), confidence = g.
    Where the render has content and the restorer has no confidence (its inputs were unreliable)
    or the pixel is observed, the render comes back unchanged: restoration never overwrites what
    it cannot support. Given ``hole``, a hole is replaced whatever the confidence: the render
    holds only the background colour there (``stage2.restore_holes``: over black any
    reference-guided guess beats it; over the train views' mean colour the learned restorer's does
    not, docs/decisions/unobserved-fill.md).
    """
    render = _as_array(render, "render")
    _check_shape(render, result.rgb.shape, "render")
    g = np.clip(np.nan_to_num(result.confidence, nan=0.0), 0.0, 1.0)
    if weight is not None:
        weight = _as_array(weight, "weight")
        _check_shape(weight, result.confidence.shape, "weight")
        g = g * np.clip(np.nan_to_num(weight, nan=0.0), 0.0, 1.0)
    if hole is not None:
        hole = _as_array(hole, "hole")
        _check_shape(hole, result.confidence.shape, "hole")
        g = np.maximum(g, np.clip(np.nan_to_num(hole, nan=0.0), 0.0, 1.0))
    # images are in [0, 1]: clipped first, so out-of-range input cannot overflow the difference
    render = np.clip(np.nan_to_num(render, nan=0.0), 0.0, 1.0)
    restored = np.clip(np.nan_to_num(result.rgb, nan=0.0), 0.0, 1.0)
    rgb = render + g[..., None] * (restored - render)
    return RestoreResult(rgb=np.clip(rgb, 0.0, 1.0), confidence=g,
                         frame_confidence=g.reshape(g.shape[0], -1).mean(axis=1))


@runtime_checkable
class Restorer(Protocol):
    """What every restorer offers. ``settings()`` is JSON-serializable (echoed into the cache).

    ``restore`` calls ``progress(fraction)`` with a fraction in [0, 1] between frames when given;
    a progress callback may raise ``RestoreCancelled`` to stop the restorer (job cancellation).
    """

    name: str

    def settings(self) -> dict[str, Any]: ...

    def restore(self, request: RestoreRequest, progress: ProgressFn | None = None) -> RestoreResult: ...
