"""The viewer on a (tiny synthetic) scene: presets, trajectory overlay, restoration -> cache ->
compare, all through the UI."""
from __future__ import annotations

import numpy as np
import pytest

from app import trajectories as traj
from app.sources import initial_state
from app.session import RestoreQueue
from app.state import TrajectorySpec
from app.view3d import COLOR_SELECTED
from app.viewer import ViewerSource
from fixer4d.scene import load_scene
from viewer_helpers import DEFAULT_WINDOW, gl_ctx, make_viewer, scene_gaussians  # noqa: F401 (fixtures)

pytestmark = pytest.mark.gl


@pytest.fixture(scope="module")
def tiny():
    return load_scene("tiny")


def _state(scene, **kw):
    src = ViewerSource(scene=scene, label="tiny", **kw)
    st = initial_state(src, scene_gaussians(scene))
    return src, st


def test_export_preset_loads_back_equal(make_viewer, tiny, tmp_path):
    src, st = _state(tiny)
    keys = (tiny.cameras[1].to_dict(), tiny.cameras[3].to_dict(), tiny.cameras[6].to_dict())
    st.trajectories = st.trajectories + [TrajectorySpec(name="custom", keyframes=keys, n_frames=9, reverse=True)]
    st.trajectories[2] = TrajectorySpec(**{**st.trajectories[2].to_dict(), "pair": (0, 3), "amplitude": 0.4,
                                           "n_frames": 5, "keyframes": ()})
    d = make_viewer(st, src, size=DEFAULT_WINDOW)
    path = tmp_path / "preset.json"
    d.viewer._traj_ui["preset"] = str(path)
    d.frame()  # the panel shows the typed path in full: the buttons below it move
    d.click_item("export_preset")
    assert path.is_file()
    assert traj.load_preset(path) == st.trajectories
    # the file is a library preset too: the cameras it holds are the ones the viewer draws
    from fixer4d.geometry.trajectory import load_presets

    for spec, tr in zip(st.trajectories, load_presets(path)):
        ours = d.viewer.trajectory_cameras(spec)
        assert len(ours) == len(tr.cameras)
        assert all(np.allclose(a.c2w, b.c2w) for a, b in zip(ours, tr.cameras))
    # and a nerfstudio camera path round-trips the poses
    ns = tmp_path / "path.json"
    traj.save_camera_path(ns, st.trajectories[-1], tiny.train_cameras, 0.25)
    back = d.viewer.trajectory_cameras(traj.load_camera_path(ns))
    assert all(np.allclose(a.c2w, b.c2w, atol=1e-9) for a, b in zip(d.viewer.trajectory_cameras(st.trajectories[-1]), back))


def test_trajectory_overlay_projects_at_the_trajectory_cameras(make_viewer, tiny):
    src, st = _state(tiny)
    arc = next(k for k, s in enumerate(st.trajectories) if s.arc_index is not None)
    st.selected_trajectory = arc
    st.show_frusta = False
    rig = np.mean([c.center for c in tiny.train_cameras], axis=0)
    st.view.look_from(rig + np.array([0.0, 2.5, 3.0]), np.array([0.0, 0.6, 0.0]))
    d = make_viewer(st, src)
    d.settle()
    shot = d.viewer.splats.read_display().astype(float)
    cam = d.viewer.render_camera
    cams = d.viewer.trajectory_cameras(st.trajectories[arc])[1:-1]  # interior: only this path passes there
    uv, z = cam.project(np.stack([c.center for c in cams]))
    assert np.all(z > 0)
    want = np.array(COLOR_SELECTED[:3]) * 255
    inside = 0
    for u, v in uv:
        if 2 <= u < cam.width - 2 and 2 <= v < cam.height - 2:
            inside += 1
            assert np.abs(shot[int(v), int(u)] - want).max() < 40, (u, v, shot[int(v), int(u)])
    assert inside >= len(cams) // 2
    # and away from the path the colour is not there
    r = np.random.default_rng(0)
    far = [(x, y) for x, y in r.uniform([0, 0], [cam.width, cam.height], (200, 2))
           if np.min(np.hypot(uv[:, 0] - x, uv[:, 1] - y)) > 30]
    assert all(np.abs(shot[int(y), int(x)] - want).max() > 40 for x, y in far)


def test_queued_restoration_lands_in_cache_and_compare_shows_it(make_viewer, tiny, tmp_path):
    from fixer4d.restore.cache import RestoreCache
    from fixer4d.restore.jobs import RestoreJobs
    from fixer4d.restore.reference_warp import ReferenceWarpRestorer

    cache = RestoreCache(tmp_path / "cache")
    queue = RestoreQueue(RestoreJobs(ReferenceWarpRestorer(), cache), lambda: 0)
    src, st = _state(tiny, cache=cache, restore=queue, render_backend="reference")
    st.trajectories = [TrajectorySpec(name="0-3", pair=(0, 3), n_frames=4)]
    st.selected_trajectory = 0
    st.set_frame(2)
    d = make_viewer(st, src)
    d.click_item("queue")
    assert queue.wait_all(timeout=300)
    assert [i.status for i in queue.items] == ["done"]
    # the pipeline's clip name (scene camera ids) with the viewer's trajectory settings after it:
    # never the pipeline's own entry
    key = cache.key(2, tiny.train_ids[0], tiny.train_ids[3]) + "_viewer_A0.000_F4"
    assert key == "t0002_0-7_viewer_A0.000_F4"
    assert cache.has(0, key) and not cache.has(0, "t0002_0-7")
    d.frame(2)
    ui = d.viewer._compare_ui
    ui["polled"] = -1e9
    d.frame(2)
    entries = ui["entries"]
    assert [e.key for e in entries] == [key]
    tex = d.viewer.images["compare_target"]
    w, h = tex.size
    shown = np.frombuffer(tex.read(alignment=1), np.uint8).reshape(h, w, 3)
    expected = (np.clip(entries[0].rgb()[0], 0, 1) * 255 + 0.5).astype(np.uint8)
    np.testing.assert_array_equal(shown, expected)
    # the clip carries where the pseudo-loss acts, and Compare shows it as a fourth pane
    hidden = entries[0].unobserved()
    assert hidden is not None and hidden.shape == entries[0].rgb().shape[:3]
    assert "compare_supervised" in d.viewer.images
    assert "compare" not in d.viewer.panel_errors
