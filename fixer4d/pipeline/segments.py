"""Long captures as overlapping temporal segments (STGS trains 50-frame segments).

A T-frame clip is cut into segments of ``frames`` frames that share ``overlap`` frames with their
neighbours; each segment is a complete run of the pipeline on its frame range (its own init,
stage 1, restoration and refinement) in ``RUN/segments/seg<k>_<a>-<b>/``. With
``share_static`` the first segment runs first and the others train on top of its static
Gaussians (``shared_static``); the others are independent, so an executor (``executors``) may
run them anywhere. A ``SegmentedModel`` stitches
the segments' models back onto the clip's timeline for evaluation and the viewer.

Time: frame f of the T-frame clip has t = f / T; inside segment [s, e) the same frame has
t_local = (f - s) / (e - s). Every frame is owned by the segment whose centre is nearest (ties go
to the earlier segment), so playback switches model in the middle of each overlap.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from fixer4d.errors import InputError


@dataclass
class SegmentConfig:
    """How a long capture is split (the segments run on the config's ``executor``)."""

    frames: int | None = None   # frames per segment; None: the whole clip is one run
    overlap: int = 2            # frames shared by neighbouring segments (stitching margin)
    # the first segment's static Gaussians, frozen, in every later segment (shared_static.py).
    # Off by default: it carries the first segment's stage-1 outcome into every segment, which
    # helped one real split (+0.9 dB) and hurt the other (-0.25 dB); README "Long captures".
    share_static: bool = False
    # set by the segmented run on the later segments' configs: the folder of the shared rows
    static_from: str | None = None

    def __post_init__(self) -> None:
        if self.frames is not None and self.frames < 2:
            raise InputError(f"segments.frames (--segment-frames) must be >= 2 (a segment needs motion to learn), "
                             f"got {self.frames}")
        if self.overlap < 0 or (self.frames is not None and self.overlap >= self.frames):
            raise InputError(f"segments.overlap must be in [0, segments.frames) = [0, {self.frames}), got {self.overlap}: "
                             "use longer segments (--segment-frames) or --set segments.overlap=N")


def split_segments(num_frames: int, frames: int, overlap: int) -> list[tuple[int, int]]:
    """Half-open frame ranges [s, e) covering [0, num_frames), each ``frames`` long (the last one
    shifted back to end at the clip's end), neighbours sharing at least ``overlap`` frames."""
    if num_frames <= frames:
        return [(0, num_frames)]
    step = frames - overlap
    out = []
    s = 0
    while True:
        e = s + frames
        if e >= num_frames:
            out.append((num_frames - frames, num_frames))
            break
        out.append((s, e))
        s += step
    return out


def owners(num_frames: int, ranges: Sequence[tuple[int, int]]) -> np.ndarray:
    """(num_frames,) index of the segment that owns each frame (nearest centre, earlier on ties)."""
    own = np.zeros(num_frames, np.int64)
    for f in range(num_frames):
        best, dist = -1, np.inf
        for k, (s, e) in enumerate(ranges):
            if s <= f < e:
                d = abs(f + 0.5 - 0.5 * (s + e))
                if d < dist - 1e-9:
                    best, dist = k, d
        if best < 0:
            raise InputError(f"frame {f} is in no segment of {list(ranges)}")
        own[f] = best
    return own


def to_local_time(t: float, num_frames: int, segment: tuple[int, int]) -> float:
    """Clip time t (= f / T) as the time of segment [s, e) (= (f - s) / (e - s))."""
    s, e = segment
    return (float(t) * num_frames - s) / float(e - s)


class SegmentedModel:
    """Segment models on one timeline: ``at(t)`` is the owning segment's snapshot at its local time.

    models: one model per segment (anything with ``at(t, camera_center)``); ranges: their frame
    ranges [s, e) in the clip's frames; num_frames: T.
    """

    def __init__(self, models: Sequence[Any], ranges: Sequence[tuple[int, int]], num_frames: int) -> None:
        if len(models) != len(ranges) or not models:
            raise InputError("SegmentedModel: one model per segment range, at least one")
        self.models = list(models)
        self.ranges = [tuple(map(int, r)) for r in ranges]
        self.num_frames = int(num_frames)
        self._owner = owners(self.num_frames, self.ranges)

    def segment_of(self, t: float) -> int:
        f = int(np.clip(np.floor(float(t) * self.num_frames + 1e-6), 0, self.num_frames - 1))
        return int(self._owner[f])

    def at(self, t: float, camera_center: np.ndarray | None = None):
        k = self.segment_of(t)
        return self.models[k].at(to_local_time(t, self.num_frames, self.ranges[k]), camera_center=camera_center)

    @property
    def num_gaussians(self) -> int:
        return int(sum(m.num_gaussians for m in self.models))


def segment_dir(run_dir: Path, k: int, seg: tuple[int, int]) -> Path:
    return Path(run_dir) / "segments" / f"seg{k:02d}_{seg[0]:05d}-{seg[1]:05d}"
