"""Level of detail while the view moves: a fixed, nested, opacity-weighted subset of the splats,
enlarged to keep the coverage; the resting frame draws every splat exactly."""
from __future__ import annotations

import numpy as np
import pytest

from app.adaptive import LOD_MIN_SPLATS, MIN_SCALE, REFINE_AFTER_FRAMES, AdaptiveResolution
from app.gl.lod import area_factor, importance_rank, lod_count, lod_subset, stable_uniform
from app.main import initial_state
from app.viewer import ViewerSource
from fixer4d.scene import load_scene
from viewer_helpers import gl_ctx, make_viewer, scene_gaussians  # noqa: F401 (fixtures)


def test_rank_is_a_fixed_permutation_weighted_by_opacity():
    logits = np.concatenate([np.full(5000, 4.0), np.full(5000, -4.0)])  # opaque, then faint
    rank = importance_rank(logits)
    assert np.array_equal(np.sort(rank), np.arange(10000))
    assert np.array_equal(rank, importance_rank(logits.copy()))  # deterministic
    first = rank < 1000  # a 10% level of detail
    assert first[:5000].sum() > 20 * max(first[5000:].sum(), 1)  # faint splats go last
    u = stable_uniform(100000)
    assert 0.0 < u.min() and u.max() < 1.0 and abs(u.mean() - 0.5) < 0.01
    # equal weights: the subset is spread evenly over the indices (hence over a scanned surface)
    flat = importance_rank(np.zeros(10000))
    assert np.histogram(np.flatnonzero(flat < 1000), bins=10, range=(0, 10000))[0].min() > 70


def test_subset_keeps_depth_order_and_is_nested():
    rank = importance_rank(np.zeros(500))
    order = np.random.default_rng(1).permutation(500)  # a depth order
    small, large = lod_subset(order, rank, 50), lod_subset(order, rank, 200)
    assert len(small) == 50 and len(large) == 200 and set(small) <= set(large)
    pos = {g: k for k, g in enumerate(order)}
    assert all(pos[a] < pos[b] for a, b in zip(large[:-1], large[1:]))  # still front to back
    assert lod_count(500, 1.0) == 500 and lod_count(500, 1e-9) == 1 and lod_count(0, 0.5) == 0
    assert area_factor(500, 50) == 10.0 and area_factor(500, 500) == 1.0


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
