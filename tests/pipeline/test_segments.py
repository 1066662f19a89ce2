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


def test_later_segments_train_on_the_first_segments_static_gaussians(tmp_path, benchmark_script):
    """share_static (opt-in): the second segment's stage-1 and final models hold the first
    segment's static rows, frozen and bit for bit (stage-1 rows, then its refined ones in stage
    2), so the static world is the same on both sides of the boundary; without it, none."""
    import json

    import torch

    from fixer4d.model.io import load_ply
    from fixer4d.pipeline.run import run_pipeline
    from pipeline_tiny import tiny_config

    base = {"segments.frames": 3, "segments.overlap": 2, "baseline_sparse": False, "eval.restoration_rows": False,
            "eval.matched_row": False, "init_frame_stride": 1, "eval.stride": 1, "restorer.kind": "warp",
            "training.iterations": 30, "stage2.refresh_every": 10}
    report = run_pipeline(tiny_config(**base, **{"segments.share_static": True}), tmp_path / "shared", progress=False)
    seg = tmp_path / "shared" / "segments"
    first, second = seg / "seg00_00000-00003", seg / "seg01_00001-00004"
    for model_file, shared in (("model_stage1.ply", "stage1.ply"), ("model_final.ply", "final.ply")):
        src = load_ply(first / model_file)
        rows = load_ply(seg / "shared_static" / shared)
        assert src.num_frozen == 0 and rows.num_gaussians == int((~src.dynamic).sum()) > 0
        assert torch.equal(rows.means, src.means[~src.dynamic]) and torch.equal(rows.colors, src.colors[~src.dynamic])
        later = load_ply(second / model_file)
        assert later.num_frozen == rows.num_gaussians
        assert torch.equal(later.means[later.frozen], rows.means)
        assert torch.equal(later.opacity_logits[later.frozen], rows.opacity_logits)
        assert not bool(later.dynamic[later.frozen].any())
    assert report["shared_static"]["stage1"] == load_ply(seg / "shared_static" / "stage1.ply").num_gaussians
    assert [s["frozen"] for s in report["segments"]] == [0, report["shared_static"]["stage1"]]
    reasons = json.loads((second / "report.json").read_text())["model"]["reasons"]
    assert "frozen static Gaussians of the first segment" in reasons["shared_static"]

    alone = run_pipeline(tiny_config(**base, **{"stage2.rounds": 0}),  # the default: no sharing
                         tmp_path / "alone", progress=False)
    assert alone["shared_static"] is None and [s["frozen"] for s in alone["segments"]] == [0, 0]
    assert not (tmp_path / "alone" / "segments" / "shared_static").exists()

    # benchmarks/segment_seams.py: both segments render every shared frame (1, 2) of each held-out camera
    seams = benchmark_script("segment_seams").seams(tmp_path / "shared")
    from fixer4d.scene import load_scene

    n_test = len(load_scene("tiny").test_ids)
    assert sorted({r["frame"] for r in seams["frames"]}) == [1, 2] and len(seams["frames"]) == 2 * n_test
    assert seams["share_static"] and all(5 < r["psnr_before"] < 60 and 5 < r["psnr_after"] < 60 for r in seams["frames"])
