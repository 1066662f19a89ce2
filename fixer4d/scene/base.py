"""The multi-view video interface every scene source implements.

A scene is a fixed rig of synchronized cameras, T frames each. Frame f has time t = f / T
(docs/design.md §4). Frames are produced lazily and cached in a bounded LRU, so a scene never holds
every frame in memory.
"""
from __future__ import annotations

import abc
import threading
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Hashable

import numpy as np

from fixer4d.errors import InputError
from fixer4d.geometry.camera import Camera
from fixer4d.geometry.rig import common_view_bounds


def frame_time(frame: int, num_frames: int) -> float:
    """t = f / T: the STGS convention, t in [0, 1)."""
    if not num_frames >= 1:
        raise InputError(f"frame_time: the clip must have at least one frame, got num_frames={num_frames}")
    return frame / float(num_frames)


# Memory for decoded / ray-cast frames per scene (MiB). Training draws random (frame, camera)
# pairs over the whole clip at every step, so a cache smaller than the train set decodes (or
# ray-casts) most frames again and again: the demo's 80 train frames plus their depth maps did
# not fit the former 128-item cache, and a stage-2 refine re-ray-cast 271 frames instead of
# ~130. 2 GiB holds the 4 train cameras of a whole 150-frame capture at 640x360 (1.66 GB; a
# video frame has no depth map) and every frame of the demo (0.47 MiB per 200x150 frame with
# its depth); past that, the least recently used frames go. Longer captures run as segments.
FRAME_CACHE_MB = 2048


class LRUCache:
    """A thread-safe least-recently-used cache bounded by the bytes of what it holds.

    Values are numpy arrays (their ``nbytes`` count) or anything else (counted as 0 bytes, e.g.
    None for "no depth"). The most recent value is always kept, even when it alone is larger
    than the budget. ``max_bytes`` 0 disables caching.
    """

    def __init__(self, max_bytes: int) -> None:
        self.max_bytes = max(0, int(max_bytes))
        self._items: OrderedDict[Hashable, object] = OrderedDict()
        self._bytes = 0
        self._lock = threading.Lock()

    @property
    def nbytes(self) -> int:
        """Bytes held now."""
        return self._bytes

    def __len__(self) -> int:
        return len(self._items)

    def get_or_compute(self, key: Hashable, compute: Callable[[], object]) -> object:
        with self._lock:
            if key in self._items:
                self._items.move_to_end(key)
                return self._items[key]
        value = compute()
        with self._lock:
            if self.max_bytes and key not in self._items:
                self._items[key] = value
                self._bytes += _nbytes(value)
                while self._bytes > self.max_bytes and len(self._items) > 1:
                    _, old = self._items.popitem(last=False)
                    self._bytes -= _nbytes(old)
        return value

    def clear(self) -> None:
        with self._lock:
            self._items.clear()
            self._bytes = 0


def _nbytes(value: object) -> int:
    return int(getattr(value, "nbytes", 0))


@dataclass(frozen=True)
class SceneBounds:
    """Depth range and an axis-aligned box that contains the scene content (world units)."""

    near: float
    far: float
    bbox_min: np.ndarray  # (3,)
    bbox_max: np.ndarray  # (3,)


class MultiViewVideo(abc.ABC):
    """Synchronized videos from a fixed camera rig.

    Attributes every implementation sets:
      name: a short identifier ("demo", "panoptic_basketball", ...).
      cameras: every camera of the rig (at the loaded resolution), index = camera index.
      train_ids / test_ids: indices into ``cameras`` (the 4 observed views / the held-out ones).
      num_frames: T. fps: playback rate (frames per second).
    """

    name: str
    cameras: list[Camera]
    train_ids: list[int]
    test_ids: list[int]
    num_frames: int
    fps: float = 30.0

    def __init__(self, cache_mb: float = FRAME_CACHE_MB) -> None:
        self._cache = LRUCache(int(cache_mb * 2 ** 20))
        self._common_bounds: SceneBounds | None = None

    # -- what implementations provide --------------------------------------------------
    @abc.abstractmethod
    def _load_frame(self, frame: int, cam: int) -> np.ndarray:
        """(H, W, 3) float32 RGB in [0, 1] for camera index ``cam`` at frame ``frame``."""

    def _load_depth(self, frame: int, cam: int) -> np.ndarray | None:
        """(H, W) float32 ground-truth z-depth (inf where nothing is hit), or None if unknown."""
        return None

    def _load_mask(self, frame: int, cam: int) -> np.ndarray | None:
        """(H, W) bool foreground mask, or None if the scene has none."""
        return None

    def bounds(self) -> SceneBounds:
        """Scene bounds from the capture's own cues, never from ground truth: layouts that store
        bounds (LLFF poses_bounds) override this; otherwise the train cameras' common view
        (``fixer4d.geometry.rig.common_view_bounds``: frustum overlap, near/far over the train
        cameras). Raises InputError when the train cameras share no view."""
        if self._common_bounds is None:
            vb = common_view_bounds(self.train_cameras)
            self._common_bounds = SceneBounds(vb.near, vb.far, vb.bbox_min, vb.bbox_max)
        return self._common_bounds

    # -- public API --------------------------------------------------------------------
    def time(self, frame: int) -> float:
        return frame_time(frame, self.num_frames)

    def frame(self, frame: int, cam: int) -> np.ndarray:
        self._check(frame, cam)
        return self._cache.get_or_compute(("rgb", frame, cam), lambda: self._load_frame(frame, cam))

    def depth(self, frame: int, cam: int) -> np.ndarray | None:
        self._check(frame, cam)
        return self._cache.get_or_compute(("depth", frame, cam), lambda: self._load_depth(frame, cam))

    def mask(self, frame: int, cam: int) -> np.ndarray | None:
        self._check(frame, cam)
        return self._load_mask(frame, cam)

    @property
    def has_depth(self) -> bool:
        return False

    @property
    def train_cameras(self) -> list[Camera]:
        return [self.cameras[i] for i in self.train_ids]

    @property
    def test_cameras(self) -> list[Camera]:
        return [self.cameras[i] for i in self.test_ids]

    def _check(self, frame: int, cam: int) -> None:
        if not 0 <= frame < self.num_frames:
            raise InputError(f"{self.name}: frame {frame} out of range [0, {self.num_frames})")
        if not 0 <= cam < len(self.cameras):
            raise InputError(f"{self.name}: camera index {cam} out of range [0, {len(self.cameras)})")

    def describe(self) -> str:
        c = self.cameras[0]
        return (f"{self.name}: {len(self.cameras)} cameras ({len(self.train_ids)} train, {len(self.test_ids)} held out), "
                f"{self.num_frames} frames at {c.width}x{c.height}")
