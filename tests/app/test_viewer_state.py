"""AppState editing (undo/redo), session persistence, camera control and the blur map."""
from __future__ import annotations

import numpy as np
import pytest

from app.camera_control import ViewCamera
from app.debug_maps import blur_map, warp_reference
from app.state import AppState, TrajectorySpec
from fixer4d.errors import InputError
from fixer4d.geometry.camera import Camera
from viewer_helpers import make_gaussians


def test_trajectory_edits_undo_redo():
    st = AppState()
    st.add_trajectory(TrajectorySpec("0-1", pair=(0, 1)))
    st.add_trajectory(TrajectorySpec("0-2", pair=(0, 2)))
    st.update_trajectory(1, "A", amplitude=0.3)
    st.update_trajectory(1, "frames", n_frames=9)
    st.delete_trajectory(0)
    assert [t.name for t in st.trajectories] == ["0-2"] and st.trajectories[0].amplitude == 0.3
    for _ in range(3):
        assert st.undo()
    assert [(t.name, t.amplitude, t.n_frames) for t in st.trajectories] == [("0-1", 0.0, 16), ("0-2", 0.0, 16)]
    assert st.redo() and st.trajectories[1].amplitude == 0.3
    st.add_trajectory(TrajectorySpec("c", keyframes=()))  # a new edit clears the redo stack
    assert not st.redo_stack
    while st.undo():
        pass
    assert st.trajectories == []


def test_isolate_and_undo_keep_exact_arrays():
    g = make_gaussians()
    st = AppState()
    st.set_gaussians(g)
    sel = np.zeros(g.n, bool)
    sel[[3, 50, g.n - 1]] = True
    st.set_selection(sel)
    assert st.isolate_selected() == 3
    assert st.gaussians.equals(g.subset(sel))
    st.undo()
    assert st.gaussians.equals(g)
    assert st.delete_selected() == 3 and st.gaussians.n == g.n - 3


def test_session_round_trip(tmp_path):
    st = AppState(num_frames=10)
    st.view = ViewCamera(target=np.array([0.1, 0.2, 0.3]), distance=3.0, yaw=0.4, pitch=-0.2, mode="fly",
                         snapped=Camera.look_at([0, 0, -2], [0, 0, 0], width=32, height=24, name="cam3"))
    st.trajectories = [TrajectorySpec("0-1", pair=(0, 1), amplitude=0.2, reverse=True)]
    st.selected_trajectory = 0
    st.set_frame(7)
    path = st.save_session(tmp_path / "s.json")
    other = AppState(num_frames=10)
    assert other.load_session(path)
    assert other.session_dict() == st.session_dict()
    assert not AppState().load_session(tmp_path / "missing.json")
    (tmp_path / "bad.json").write_text("{\"version\": 1}")
    with pytest.raises(InputError, match="bad.json"):
        AppState().load_session(tmp_path / "bad.json")


def test_orbit_keeps_target_fly_keeps_eye():
    v = ViewCamera(target=np.zeros(3), distance=5.0)
    v.rotate(40, 10)
    assert np.isclose(np.linalg.norm(v.eye() - v.target), 5.0)
    v.mode = "fly"
    eye = v.eye()
    v.rotate(-30, 5)
    np.testing.assert_allclose(v.eye(), eye, atol=1e-9)
    cam = Camera.look_at([1.0, -0.5, -3.0], [0, 0, 0], width=40, height=30, name="c")
    v.snap_to(cam)
    snapped = v.camera(40, 30)
    np.testing.assert_array_equal(snapped.c2w, cam.c2w)
    np.testing.assert_allclose(v.camera(80, 60).K[:2], 2 * cam.K[:2])


def test_blur_map_flags_missing_detail_only():
    cam = Camera.look_at([0, 0, -3], [0, 0, 0], width=48, height=40)
    rng = np.random.default_rng(0)
    sharp = rng.uniform(0, 1, (40, 48, 3)).astype(np.float32)
    depth = np.full((40, 48), 3.0, np.float32)
    alpha = np.ones((40, 48), np.float32)
    warped, valid = warp_reference(sharp, cam, cam, depth, alpha)
    np.testing.assert_allclose(warped[valid], sharp[valid], atol=1e-5)  # identity warp, pixel centres
    assert valid.mean() > 0.95
    assert blur_map(sharp, depth, alpha, cam, sharp, cam).max() < 1e-5
    flat = np.full_like(sharp, 0.5)
    assert blur_map(flat, depth, alpha, cam, sharp, cam).mean() > 0.1


def test_compare_grid_fills_the_panel():
    from app.panels.compare import grid_layout

    # three 4:3 images in a wide, short panel: one row; in a tall, narrow one: one column
    cols, scale = grid_layout(3, 200, 150, 800, 290, 20)
    assert cols == 3 and abs(scale - min((800 - 24) / 600, (290 - 28) / 150)) < 1e-9
    cols, scale = grid_layout(3, 200, 150, 330, 900, 20)
    assert cols == 1 and scale > 1.5
    # a square panel: a 2-column grid beats both a row and a column
    cols, scale = grid_layout(3, 200, 150, 700, 600, 20)
    assert cols == 2 and scale > 1.5  # one row: 1.13, one column: 1.15


def test_loss_plot_shows_only_terms_that_exist():
    from app.panels.training import plotted_series

    stage1 = [{"loss": 0.5 - 0.01 * i, "loss_stg": 0.5 - 0.01 * i, "loss_gen": 0.0, "psnr": 20.0} for i in range(5)]
    assert list(plotted_series(stage1)) == ["loss"]
    stage2 = [{"loss": 0.6 - 0.01 * i, "loss_stg": 0.5 - 0.01 * i, "loss_gen": 0.1} for i in range(5)]
    assert list(plotted_series(stage2)) == ["loss", "loss_stg", "loss_gen"]
    assert plotted_series([{"psnr": 20.0}]) == {}


def test_adaptive_resolution_plans():
    from app.adaptive import MIN_SCALE, REFINE_AFTER_FRAMES, AdaptiveResolution

    a = AdaptiveResolution(budget_ms=40.0)
    assert a.plan("v0") == 1.0  # no cost estimate yet: full size
    a.done(1.0, 640.0, complete=True)
    assert a.final and a.plan("v0") is None  # unchanged and final: nothing to draw
    s = a.plan("v1")  # the view moves: 640 ms at full size -> 1/4 of the pixels fits 40 ms
    assert s == 0.25 and a.moving
    a.done(s, 40.0, complete=True)
    assert not a.final
    for _ in range(REFINE_AFTER_FRAMES - 1):
        assert a.plan("v1") is None  # resting briefly: keep the quick image
    assert a.plan("v1") == 1.0 and not a.moving  # then refine once at full size
    a.done(1.0, 640.0, complete=False)  # drawn with an old depth order: not final yet
    assert a.plan("v1") == 1.0
    a.full_cost_ms = 1e6
    assert a.plan("v2") == MIN_SCALE  # never below the floor
