"""A segmented run (``fixer4d run SCENE --segment-frames F``) as one model on the clip's timeline.

Such a run has no top-level model: each temporal segment is a complete run in
``RUN/segments/seg<k>_<s>-<e>/`` (``fixer4d.pipeline.segments.segment_dir``) with its own
``model_final.ply`` (or ``model_stage1.ply`` when it stopped after stage 1). The viewer shows, at
clip time t, the model of the segment that owns t's frame at that segment's local time, exactly
as ``fixer4d.pipeline.segments.SegmentedModel`` stitches them for evaluation (the same owners and
time mapping), so playback switches model in the middle of each overlap.
"""
from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from app.gaussians import GaussianArrays
from fixer4d.errors import InputError
from fixer4d.pipeline.segments import SegmentedModel, owners, to_local_time

# A segment folder's name: seg<k>_<start>-<stop> (segments.segment_dir), frames of the clip.
SEGMENT_DIR = re.compile(r"^seg(\d+)_(\d+)-(\d+)$")
# A segment's model, most refined first (after the viewer's newest edit of it, see segment_model).
SEGMENT_MODELS = ("model_final.ply", "model_stage1.ply")


def segment_model(folder: Path) -> Path | None:
    """The model a segment opens with: the viewer's newest edit (``model_edit_<k>.ply``, saved by
    "save as new model version" while the segment was shown), else SEGMENT_MODELS in order."""
    from app.files import EDIT_PATTERN

    edits = [(int(m.group(1)), p) for p in Path(folder).glob("model_edit_*.ply") if (m := EDIT_PATTERN.match(p.name))]
    if edits:
        return max(edits)[1]
    return next((Path(folder) / name for name in SEGMENT_MODELS if (Path(folder) / name).is_file()), None)


def segment_models(run: Path) -> list[tuple[tuple[int, int], Path]]:
    """((start, stop), model path) of each segment of a run folder, in segment order; empty when
    the run has no segments. Raises InputError when a segment has no model yet."""
    root = Path(run) / "segments"
    if not root.is_dir():
        return []
    found = []
    for d in sorted(root.iterdir()):
        m = SEGMENT_DIR.match(d.name)
        if not d.is_dir() or m is None:
            continue
        model = segment_model(d)
        if model is None:
            raise InputError(f"{d}: segment without a model ({' or '.join(SEGMENT_MODELS)}); is the run finished?")
        found.append((int(m.group(1)), (int(m.group(2)), int(m.group(3))), model))
    found.sort()
    return [(rng, path) for _, rng, path in found]


@dataclass
class SegmentTimeline:
    """The segments' Gaussians on one timeline of ``num_frames`` frames.

    arrays: one GaussianArrays per segment (edits of a segment are kept here when the viewer
    switches away from it); ranges: their frame ranges [s, e) in the clip; paths: their files.
    """

    arrays: list[GaussianArrays]
    ranges: list[tuple[int, int]]
    num_frames: int
    paths: list[Path]

    def __post_init__(self) -> None:
        self._owner = owners(self.num_frames, self.ranges)  # checks that the ranges cover the clip

    @classmethod
    def load(cls, run: Path, num_frames: int) -> "SegmentTimeline":
        from fixer4d.model.io import load_model

        segs = segment_models(run)
        if not segs:
            raise InputError(f"{run}: no segments (RUN/segments/seg<k>_<s>-<e>/)")
        return cls([GaussianArrays.from_model(load_model(p)) for _, p in segs], [r for r, _ in segs], int(num_frames),
                   [p for _, p in segs])

    def segment_of(self, t: float) -> int:
        """The segment that owns clip time t (t = f / T)."""
        f = int(np.clip(np.floor(float(t) * self.num_frames + 1e-6), 0, self.num_frames - 1))
        return int(self._owner[f])

    def local_time(self, t: float) -> float:
        """Clip time t as the owning segment's time."""
        return to_local_time(t, self.num_frames, self.ranges[self.segment_of(t)])

    def stitched(self, models: list[Any]) -> SegmentedModel:
        """``SegmentedModel`` of per-segment models (e.g. the arrays' torch models)."""
        return SegmentedModel(models, self.ranges, self.num_frames)

    @property
    def num_gaussians(self) -> int:
        return int(sum(g.n for g in self.arrays))

    def cache_entries(self) -> list[Any]:
        """Every segment's restored clips (each segment run's latest round) on this timeline: frame
        and time as in the whole clip (a segment's own are local to it), key prefixed with the
        segment's folder so clips of different segments never share a name."""
        import dataclasses

        from fixer4d.restore.cache import RestoreCache

        out = []
        for (start, _), path in zip(self.ranges, self.paths):
            seg_dir = path.parent  # the segment's run folder (the model may be one of its edits)
            for entry in RestoreCache(seg_dir / "cache").entries():
                f = start + int(entry.frame)
                out.append(dataclasses.replace(entry, key=f"{seg_dir.name}/{entry.key}", frame=f,
                                               time=f / float(self.num_frames)))
        return out
