"""A segmented run folder (``fixer4d run --segment-frames F``: RUN/segments/seg<k>_<s>-<e>/ with a
model each and no top-level model) plays as one model on the clip's timeline: at every frame the
viewer shows the owning segment's Gaussians at its local time, as SegmentedModel stitches them
for evaluation."""
from __future__ import annotations

import json

import numpy as np
import pytest

from app.sources import app_services
import torch

from app.gl.splats import SplatRenderer
from app.sources import initial_state, open_source
from app.segments import SegmentTimeline, segment_models
from fixer4d.model.io import save_ply
from fixer4d.pipeline.segments import owners, segment_dir, split_segments, to_local_time
from fixer4d.render.api import render
from fixer4d.scene import load_scene
from viewer_helpers import DEFAULT_WINDOW, Driver, gl_ctx, scene_gaussians  # noqa: F401 (fixture)

pytestmark = pytest.mark.gl


def _segment_arrays(scene, k: int, start: int):
    """Surfaces of the segment's first frame plus a moving part: every 3rd Gaussian is dynamic
    and moves along x with the segment's local time (a wrong time mapping moves it elsewhere);
    each segment's colours are tinted differently."""
    g = scene_gaussians(scene, frame=start, stride=6)
    g.dynamic[::3] = True
    g.motion[::3, 0] = 0.6 if k == 0 else -0.6
    g.t_center[:] = 0.5
    g.colors[:, k] += 0.8
    return g


@pytest.fixture
def segmented_run(tmp_path):
    """The tiny scene (4 frames) in 3-frame segments overlapping by 2, as `fixer4d run` lays it
    out (format-2 config.json, segment folders named by segment_dir), without running it."""
    scene = load_scene("tiny")
    run = tmp_path / "segrun"
    ranges = split_segments(scene.num_frames, 3, 2)
    arrays = []
    for k, rng in enumerate(ranges):
        d = segment_dir(run, k, rng)
        d.mkdir(parents=True)
        arrays.append(_segment_arrays(scene, k, rng[0]))
        save_ply(arrays[-1].to_model(), d / "model_final.ply")
    (run / "config.json").write_text(json.dumps({"format_version": 2, "config": {
        "scene": {"source": "tiny", "scale": 1.0, "frame_range": None}, "segments": {"frames": 3, "overlap": 2}}}))
    return run, scene, ranges, arrays


def test_segmented_run_plays_along_one_timeline(gl_ctx, segmented_run, tmp_path, monkeypatch):
    from app.viewer import Viewer

    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "cfg"))
    run, scene, ranges, arrays = segmented_run
    assert [r for r, _ in segment_models(run)] == ranges == [(0, 3), (1, 4)]
    src, g, session_dir = open_source(str(run))
    assert isinstance(src.segments, SegmentTimeline) and src.model_path is None
    st = initial_state(src, g)
    st.show_frusta = st.show_trajectories = False
    v = Viewer(gl_ctx, st, src, services=app_services(), session_path=session_dir / "session.json")
    reference = SplatRenderer(gl_ctx)
    try:
        d = Driver(v, gl_ctx, DEFAULT_WINDOW)
        d.frame(2)
        assert st.num_frames == scene.num_frames == 4
        own = owners(scene.num_frames, ranges)
        assert list(own) == [0, 0, 1, 1]  # the switch falls in the middle of the overlap
        st.fps, st.loop = 1.0, False
        d.press("space", frames_held=1, dt=0.0)  # play, as a user would
        assert st.playing
        seen = []
        for f in range(scene.num_frames):
            assert st.frame == f
            k = int(own[f])
            t_local = to_local_time(f / scene.num_frames, scene.num_frames, ranges[k])
            assert v.state.gaussians is src.segments.arrays[k] and v.model_time() == pytest.approx(t_local)
            st.playing = False
            d.settle()
            shown = v.splats.read_rgb()
            reference.set_gaussians(arrays[k])
            reference.render(v.render_camera, t_local, wait_sort=True)
            assert np.array_equal(shown, reference.read_rgb())  # the owning segment at its local time
            seen.append(shown)
            st.playing = True
            d.frame(1, dt=1.0)  # one frame at 1 fps
        assert not np.array_equal(seen[1], seen[2])  # the segments differ: the switch is visible
        # compare/restore renders (torch) follow the same timeline
        cam = scene.cameras[scene.train_ids[0]]
        for f in range(scene.num_frames):
            k = int(own[f])
            t_local = to_local_time(f / scene.num_frames, scene.num_frames, ranges[k])
            with torch.no_grad():
                want = render(arrays[k].to_model().snapshot(t_local, cam.center), cam, background=tuple(st.background))
            got = v.gaussians_render_fn()(cam, f / scene.num_frames)["rgb"]
            assert np.allclose(got, want.rgb.clamp(0, 1).numpy(), atol=1e-6)
        # an edit of a segment saves into that segment's folder and reopens there
        st.set_frame(3)
        d.settle()
        st.set_selection(np.arange(st.gaussians.n) < 10)
        st.delete_selected()
        n_edit = st.gaussians.n
        path = v.save_edited_model()
        assert path.parent.name == "seg01_00001-00004" and path.name == "model_edit_1.ply"
    finally:
        reference.release()
        v.close()
    src2, _, _ = open_source(str(run))
    assert src2.segments.paths[1] == path and src2.segments.arrays[1].n == n_edit
    assert src2.segments.arrays[0].n == arrays[0].n


def test_compare_lists_the_segments_clips_on_the_clip_timeline(gl_ctx, segmented_run, tmp_path, monkeypatch):
    """A segmented run keeps its restored clips in each segment's run folder; the Compare panel
    showed "no finished clips" for it. The clips now list with whole-clip frames and times."""
    import dataclasses

    from app.panels.compare import refresh_entries
    from app.viewer import Viewer
    from fixer4d.bench.restore import make_request
    from fixer4d.restore.base import RestoreResult
    from fixer4d.restore.cache import RestoreCache

    monkeypatch.setenv("XDG_CONFIG_HOME", str(tmp_path / "cfg"))
    run, scene, ranges, _ = segmented_run
    request, gt = make_request(32, 24, 3, seed=0)
    seg1 = segment_dir(run, 1, ranges[1])
    local = dataclasses.replace(request, frame=1, time=1 / (ranges[1][1] - ranges[1][0]))
    result = RestoreResult(rgb=gt, confidence=np.ones(gt.shape[:3], np.float32), frame_confidence=np.ones(3, np.float32))
    RestoreCache(seg1 / "cache").write(0, RestoreCache.key(1, 0, 2), local, result, {"restorer": "test"})

    src, g, session_dir = open_source(str(run))
    entries = src.segments.cache_entries()
    assert [(e.key, e.frame) for e in entries] == [(f"{seg1.name}/t0001_0-2", ranges[1][0] + 1)]
    assert entries[0].time == pytest.approx((ranges[1][0] + 1) / scene.num_frames)
    v = Viewer(gl_ctx, initial_state(src, g), src, services=app_services(), session_path=session_dir / "session.json")
    d = Driver(v, gl_ctx, DEFAULT_WINDOW)
    d.frame(2)
    ui = v._compare_ui
    ui["polled"] = -1e9
    assert [e.key for e in refresh_entries(v, ui)] == [entries[0].key]
    d.frame(2)
    assert "compare" not in v.panel_errors
    v.close()
