"""Long captures as temporal segments: splitting, time mapping across boundaries, stitching."""
from __future__ import annotations

import numpy as np
import pytest

from fixer4d.errors import InputError
from fixer4d.pipeline.segments import SegmentConfig, SegmentedModel, owners, split_segments, to_local_time


@pytest.mark.parametrize("T, F, O", [(150, 50, 2), (20, 8, 2), (7, 3, 1), (10, 10, 2), (5, 8, 2), (31, 6, 0)])
def test_segments_cover_the_clip_with_the_overlap(T, F, O):
    ranges = split_segments(T, F, O)
    assert ranges[0][0] == 0 and ranges[-1][1] == T
    for (s0, e0), (s1, e1) in zip(ranges, ranges[1:]):
        assert s0 < s1 and e0 - s1 >= O  # neighbours share at least the overlap
    assert all(e - s == min(F, T) for s, e in ranges)
    own = owners(T, ranges)
    for f in range(T):  # every frame is owned by a segment that contains it
        s, e = ranges[own[f]]
        assert s <= f < e
    assert np.all(np.diff(own) >= 0)  # ownership moves forward only: one switch per boundary


def test_local_time_maps_frames_exactly():
    T, seg = 20, (6, 14)
    for f in range(seg[0], seg[1]):
        assert to_local_time(f / T, T, seg) == pytest.approx((f - seg[0]) / (seg[1] - seg[0]))


class _Clock:
    """A stand-in model whose snapshot is the local time it was asked for."""

    num_gaussians = 1

    def __init__(self, k):
        self.k = k

    def at(self, t, camera_center=None):
        return (self.k, t)


def test_a_gaussian_time_maps_across_segment_boundaries():
    T = 20
    ranges = split_segments(T, 8, 2)
    model = SegmentedModel([_Clock(k) for k in range(len(ranges))], ranges, T)
    for f in range(T):
        k, t_local = model.at(f / T)
        s, e = ranges[k]
        assert s <= f < e and t_local == pytest.approx((f - s) / (e - s))
        assert 0.0 <= t_local < 1.0


def test_segment_config_is_checked():
    with pytest.raises(InputError):
        SegmentConfig(frames=1)
    with pytest.raises(InputError):
        SegmentConfig(frames=4, overlap=4)


def test_segmented_run_stitches_segment_models(tmp_path, stage_cache):
    """A 4-frame tiny clip in two 3-frame segments: two complete runs and one whole-clip evaluation."""
    import json

    from fixer4d.pipeline import report as R
    from fixer4d.pipeline.run import run_pipeline
    from pipeline_tiny import tiny_config

    cfg = tiny_config(**{"segments.frames": 3, "segments.overlap": 2, "stage2.rounds": 0, "baseline_sparse": False,
                         "eval.restoration_rows": False, "init_frame_stride": 1, "eval.stride": 1})
    report = run_pipeline(cfg, tmp_path / "seg", progress=False, stage_cache=stage_cache)
    assert [r["method"] for r in report["rows"]] == [R.ROW_MVS]
    assert [s["frames"] for s in report["segments"]] == [[0, 3], [1, 4]]
    assert report["rows"][0]["psnr"] > 5 and report["peak_rss_mb"] > 0
    metrics = json.loads((tmp_path / "seg" / "eval" / "stgs-w-mvs" / "metrics.json").read_text())
    assert metrics["protocol"]["frames"] == [0, 1, 2, 3]  # the whole clip, not a segment
    for d in ("seg00_00000-00003", "seg01_00001-00004"):
        assert (tmp_path / "seg" / "segments" / d / "model_stage1.ply").is_file()
