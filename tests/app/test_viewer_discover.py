"""Discoverable: tooltips on hover, a Help window with every binding, and new work visible (a
"render video" job with progress and its result). The layout at 1024x640 and 1440x900:
test_viewer_layout.py; a tooltip on every control: test_viewer_tooltips.py."""
from __future__ import annotations

from pathlib import Path

import pytest

from app.sources import app_services, initial_state
from app.viewer import ViewerSource
from doc_shots import save_shot
from fixer4d.scene import load_scene
from viewer_helpers import gl_ctx, make_viewer, scene_gaussians  # noqa: F401 (fixtures)

pytestmark = pytest.mark.gl


@pytest.fixture(scope="module")
def tiny():
    return load_scene("tiny")


def test_a_tooltip_appears_on_hover(make_viewer, tiny, tmp_path):
    src = ViewerSource(scene=tiny, label="tiny")
    d = make_viewer(initial_state(src, scene_gaussians(tiny, stride=8)), src)
    v = d.viewer
    x0, y0, x1, y1 = v.item_rects["reset_view"]
    d.move((x0 + x1) / 2, (y0 + y1) / 2)
    for _ in range(20):  # the mouse rests on the button (imgui waits a moment before a tooltip)
        d.frame()
        if v.tooltip_shown:
            break
    assert v.tooltip_shown == "back to the first view of this scene"
    d.frame()  # imgui sizes a new tooltip window in its first frame and draws it from the next
    save_shot(v.screenshot(d.fbo), "viewer_tooltip", tmp_path)
    d.move(x1 + 200, y1 + 200)  # away: gone
    d.frame(2)
    assert v.tooltip_shown != "back to the first view of this scene"


def test_help_lists_every_shortcut(make_viewer, tiny):
    from app.panels.help import bindings
    from app.shortcuts import SHORTCUTS

    src = ViewerSource(scene=tiny, label="tiny")
    d = make_viewer(initial_state(src, None), src)
    d.click_item("menu_help")
    d.click_item("menu_help_keys")
    d.frame()
    assert d.viewer.show_help and "help" in d.viewer.window_rects
    listed = " ".join(what for what, _ in bindings())
    assert all(("Ctrl+" if ctrl else "") + (key.upper() if len(key) == 1 else key) in listed for key, ctrl in SHORTCUTS)


def test_render_video_runs_in_the_background_and_shows_its_result(make_viewer, tiny, tmp_path):
    written = {}

    def fake_video(render_fn, cameras, times, out, *, fps, progress, should_stop):
        for k, (cam, t) in enumerate(zip(cameras, times)):
            written.setdefault("frames", []).append(render_fn(cam, t)["rgb"].shape)
            progress((k + 1) / len(cameras))
        Path(out).write_bytes(b"video")
        written["times"], written["fps"] = list(times), fps
        return Path(out)

    src = ViewerSource(scene=tiny, label="tiny", run_dir=tmp_path)
    st = initial_state(src, scene_gaussians(tiny, stride=8))
    st.trajectories = st.trajectories[:1]
    st.set_frame(2)
    d = make_viewer(st, src, services=app_services(render_video=fake_video))
    d.click_item("render_video")
    job = d.viewer.__dict__["_video_ui"]["job"]
    job.wait(60)
    d.frame(2)
    assert job.error is None and job.result == tmp_path / "viewer" / "videos" / f"{st.trajectories[0].name}_f0002.mp4"
    assert job.result.read_bytes() == b"video" and job.progress == 1.0
    n = len(d.viewer.trajectory_cameras(st.trajectories[0]))
    assert len(written["frames"]) == n and written["times"][0] == pytest.approx(2 / st.num_frames)
    assert "video_open" in d.viewer.item_rects  # the result's path and an "open" button show


def test_pair_names_use_scene_camera_ids(tiny):
    src = ViewerSource(scene=tiny, label="tiny")
    st = initial_state(src, None)
    ids = tiny.train_ids
    first = st.trajectories[0]
    assert first.name == f"{ids[first.pair[0]]}-{ids[first.pair[1]]}"
    from app.trajectories import default_specs

    specs = default_specs(tiny.train_cameras, 4, camera_ids=[0, 5, 10, 15])  # a rig with ids as Panoptic's
    by_pair = {spec.pair: spec.name for spec in specs if spec.arc_index is None}
    assert by_pair[(0, 3)] == "0-15" and any(name.startswith("0-15_arc") or name.startswith("5-10_arc")
                                             for name in (s.name for s in specs if s.arc_index is not None))


def test_render_video_writes_a_playable_mp4_through_the_library(make_viewer, tiny, tmp_path):
    import av

    src = ViewerSource(scene=tiny, label="tiny", run_dir=tmp_path)
    st = initial_state(src, scene_gaussians(tiny, stride=8))
    st.trajectories = st.trajectories[:1]
    d = make_viewer(st, src, services=app_services())
    d.click_item("render_video")
    job = d.viewer.__dict__["_video_ui"]["job"]
    job.wait(120)
    assert job.error is None and job.progress == 1.0 and job.result.suffix == ".mp4"
    with av.open(str(job.result)) as container:
        frames = [f for f in container.decode(video=0)]
    n = len(d.viewer.trajectory_cameras(st.trajectories[0]))
    assert len(frames) == n and (frames[0].width, frames[0].height) == (tiny.cameras[0].width, tiny.cameras[0].height)
