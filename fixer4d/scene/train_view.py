"""``TrainOnlyView``: a scene restricted to some of its train cameras, for every stage but evaluation.

Held-out cameras are for evaluation only. A stage that trains, fits, initializes or chooses
anything receives this view: reading a frame, mask or depth of any camera that is not one of the
scene's train cameras raises ``HeldOutAccess`` (an error, never an ``assert`` that ``python -O``
drops), and the scene bounds are those of the train cameras. The view may also run at a lower
resolution (``scale``): cameras and frames are resized together.
"""
from __future__ import annotations

from collections import OrderedDict
from typing import Sequence

import cv2
import numpy as np

from fixer4d.errors import InputError
from fixer4d.geometry.camera import Camera


# Resized frames kept in memory (an LRU): a leave-one-out fold at half resolution reads each of its
# frames many times; 256 frames of 320x180 are ~180 MB, and the whole-resolution base scene keeps
# its own bounded cache.
RESIZED_FRAMES_KEPT = 256


class HeldOutAccess(InputError):
    """A stage asked for a held-out camera's data through a train-only view."""


class TrainOnlyView:
    """``base`` seen through ``train_ids`` (a subset of ``base.train_ids``) at ``scale``.

    Attributes as a MultiViewVideo: ``name``, ``train_ids`` (the cameras a stage may train on),
    ``test_ids`` (empty), ``num_frames``, ``fps``, ``cameras`` (every camera, scaled: poses of
    held-out cameras are not data), ``train_cameras``; methods ``time``, ``bounds``, ``frame``,
    ``mask``, ``depth``, ``describe``. Frames of the ``readable`` cameras may be read (default: any
    of ``base.train_ids``, so that a leave-one-out fold can score its held-back train camera; a
    fold's own stages get a view whose ``readable`` are its train cameras only); anything else
    raises HeldOutAccess.
    """

    def __init__(self, base, train_ids: Sequence[int] | None = None, scale: float = 1.0,
                 readable: Sequence[int] | None = None) -> None:
        allowed = set(int(i) for i in base.train_ids)
        train_ids = list(base.train_ids) if train_ids is None else [int(i) for i in train_ids]
        if not set(train_ids) <= allowed:
            raise InputError(f"train-only view: cameras {sorted(set(train_ids) - allowed)} are not train cameras")
        if readable is not None:
            readable_set = set(int(i) for i in readable)
            if not set(train_ids) <= readable_set <= allowed:
                raise InputError(f"train-only view: readable cameras {sorted(readable_set)} must hold the train "
                                 f"cameras {train_ids} and be train cameras of {base.name}")
            allowed = readable_set
        if not scale > 0:
            raise InputError(f"train-only view: scale must be > 0, got {scale}")
        self._base = base
        self._allowed = allowed
        self.name = f"{base.name}[{','.join(map(str, train_ids))}]"
        self.train_ids = train_ids
        self.test_ids: list[int] = []
        self.num_frames = base.num_frames
        self.fps = getattr(base, "fps", 30.0)
        self.scale = float(scale)
        self.cameras: list[Camera] = [c.scaled(scale) if scale != 1.0 else c for c in base.cameras]
        self._frames: OrderedDict[tuple[int, int], np.ndarray] = OrderedDict()

    @property
    def readable_ids(self) -> list[int]:
        """The cameras whose frames this view reads (its train cameras and, by default, the base
        scene's other train cameras), sorted."""
        return sorted(self._allowed)

    @property
    def train_cameras(self) -> list[Camera]:
        return [self.cameras[i] for i in self.train_ids]

    @property
    def test_cameras(self) -> list[Camera]:
        return []

    @property
    def has_depth(self) -> bool:
        return bool(getattr(self._base, "has_depth", False))

    def time(self, frame: int) -> float:
        return self._base.time(frame)

    def bounds(self):
        return self._base.bounds()

    def describe(self) -> str:
        return f"{self.name}: train-only view of {len(self.train_ids)} camera(s) at scale {self.scale:g}"

    def _guard(self, cam: int, what: str) -> None:
        if int(cam) not in self._allowed:
            raise HeldOutAccess(f"{what} of camera {cam} was asked for outside evaluation, but it is not a train "
                                f"camera of {self._base.name}: held-out cameras are for evaluation only")

    def frame(self, frame: int, cam: int) -> np.ndarray:
        """(H, W, 3) float32 frame of a train camera, resized to the view's scale."""
        self._guard(cam, "a frame")
        if self.scale == 1.0:
            return self._base.frame(frame, cam)  # the base scene's own bounded cache
        key = (int(frame), int(cam))
        if key in self._frames:
            self._frames.move_to_end(key)
            return self._frames[key]
        img = self._base.frame(frame, cam)
        c = self.cameras[cam]
        if img.shape[:2] != (c.height, c.width):
            img = cv2.resize(img, (c.width, c.height), interpolation=cv2.INTER_AREA)
        self._frames[key] = np.ascontiguousarray(img, dtype=np.float32)
        while len(self._frames) > RESIZED_FRAMES_KEPT:
            self._frames.popitem(last=False)
        return self._frames[key]

    def mask(self, frame: int, cam: int) -> np.ndarray | None:
        """The scene's own foreground segmentation of a train camera (None where it has none),
        resized like ``frame``."""
        self._guard(cam, "a mask")
        m = self._base.mask(frame, cam)
        c = self.cameras[cam]
        if m is None or m.shape[:2] == (c.height, c.width):
            return m
        return cv2.resize(np.asarray(m, np.uint8), (c.width, c.height), interpolation=cv2.INTER_NEAREST).astype(bool)

    def depth(self, frame: int, cam: int) -> np.ndarray | None:
        """A train camera's ground-truth depth where the scene has one (synthetic scenes: for the
        init's quality metrics only), at the base scene's resolution."""
        self._guard(cam, "a depth map")
        return self._base.depth(frame, cam) if self.scale == 1.0 else None


__all__ = ["TrainOnlyView", "HeldOutAccess"]
