"""Level of detail while the view moves: the most important splats for the view (projected
area x opacity, never a random subset), enlarged to keep the screen coverage; the resting frame
draws every splat exactly."""
from __future__ import annotations

import numpy as np
import pytest

from app.adaptive import LOD_MIN_SPLATS, MIN_SCALE, REFINE_AFTER_FRAMES, AdaptiveResolution
from app.gl.lod import area_factor, lod_count, lod_subset, screen_importance
from app.sources import initial_state
from app.viewer import ViewerSource
from fixer4d.scene import load_scene
from viewer_helpers import gl_ctx, make_viewer, scene_gaussians  # noqa: F401 (fixtures)


def test_importance_is_screen_area_times_opacity():
    z = np.array([1.0, 1.9, 1.0, 1.0])
    log_scales = np.log(np.array([[0.1, 0.01, 0.01], [0.1, 0.1, 0.1], [0.05, 0.05, 0.05], [0.1, 0.1, 0.1]]))
    opacity = np.array([1.0, 1.0, 1.0, 0.1])
    area, imp = screen_importance(z, log_scales, opacity, focal=100.0)
    np.testing.assert_allclose(area, [100.0, 100 / 1.9 ** 2, 25.0, 100.0], rtol=1e-5)  # (0.1 * 100 / 1)^2, ...
    np.testing.assert_allclose(imp, [100.0, 100 / 1.9 ** 2, 25.0, 10.0], rtol=1e-5)
    # deterministic: the same inputs choose the same splats; a near large opaque one always stays
    order = np.array([0, 2, 3, 1])  # a depth order
    assert list(lod_subset(order, imp, 2)) == [0, 1]  # the two largest, still in depth order
    assert list(lod_subset(order, imp, 2)) == list(lod_subset(order.copy(), imp.copy(), 2))


def test_subset_keeps_depth_order_and_is_the_top_importance():
    rng = np.random.default_rng(1)
    imp = rng.uniform(size=500)
    order = rng.permutation(500)  # a depth order
    small, large = lod_subset(order, imp, 50), lod_subset(order, imp, 200)
    assert len(small) == 50 and len(large) == 200 and set(small) <= set(large)
    assert set(small) == set(np.argsort(-imp)[:50])
    pos = {g: k for k, g in enumerate(order)}
    assert all(pos[a] < pos[b] for a, b in zip(large[:-1], large[1:]))  # still front to back
    assert lod_count(500, 1.0) == 500 and lod_count(500, 1e-9) == 1 and lod_count(0, 0.5) == 0
    assert area_factor(100.0, 50.0, 500, 50) == 2.0  # the kept half of the area doubles
    assert area_factor(100.0, 1.0, 500, 50) == 10.0  # capped at n / count
    assert area_factor(100.0, 100.0, 500, 500) == 1.0


def test_moving_plan_draws_fewer_splats_and_the_rest_frame_all():
    a = AdaptiveResolution(budget_ms=40.0, splats=100_000)
    a.plan("v0")
    a.done(1.0, 800.0, complete=True)
    s = a.plan("v1")  # moving: 800 ms in full -> 1/20 of the work
    assert a.fraction == pytest.approx(0.05) and s == 0.1875  # sqrt(1/20) rounded down to 1/16 steps
    a.done(s, 40.0, complete=True, fraction=a.fraction)
    assert not a.final  # a subset is never the final image
    for _ in range(REFINE_AFTER_FRAMES - 1):
        assert a.plan("v1") is None
    assert a.plan("v1") == 1.0 and a.fraction == 1.0
    a.done(1.0, 800.0, complete=True, fraction=1.0)
    assert a.final
    a.full_cost_ms = 1e9
    assert a.plan("v2") == MIN_SCALE
    assert a.fraction == LOD_MIN_SPLATS / 100_000  # never below the floor
    a.lod = False
    a.plan("v3")
    assert a.fraction == 1.0  # level of detail off: scale only


@pytest.mark.gl
def test_orbit_draws_a_subset_then_rests_exact(make_viewer):
    tiny = load_scene("tiny")
    src = ViewerSource(scene=tiny, label="tiny")
    g = scene_gaussians(tiny, stride=1)
    st = initial_state(src, g)
    st.show_frusta = st.show_trajectories = False
    d = make_viewer(st, src)
    v = d.viewer
    d.settle()
    exact = v.splats.read_rgb()
    full = v.splats.stats.instances
    assert v.splats.stats.fraction == 1.0 and full > 0.9 * g.n
    v.adaptive.full_cost_ms = 1e6  # as on a slow GL: the moving frame gets a small share
    st.view.rotate(20.0, 0.0, 400)
    d.frame()
    moving = v.splats.stats
    assert moving.fraction < 0.5 and moving.instances < 0.5 * full and not v.adaptive.final
    st.view.rotate(-20.0, 0.0, 400)  # back where it was
    d.settle()
    assert v.adaptive.final and v.splats.stats.fraction == 1.0 and v.splats.stats.instances == full
    assert np.array_equal(v.splats.read_rgb(), exact)  # the resting frame is the exact one
