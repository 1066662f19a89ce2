"""The harmonic fill of what no train camera sees (restore.unobserved_fill) and the restoration
gate that falls back on it (pipeline.restoration.gate_restoration)."""
from __future__ import annotations

import numpy as np
import pytest

from fixer4d.errors import InputError
from fixer4d.pipeline.restoration import gate_restoration
from fixer4d.restore.base import RestoreRequest, RestoreResult
from fixer4d.restore.unobserved_fill import (MIN_BOUNDARY_WEIGHT, background_boundary_weights, fill_unobserved,
                                             harmonic_fill)
from fixer4d.restore.visibility import VisibilityConfig
from tests.restore.test_visibility import _camera


def _ramp(h: int = 40, w: int = 60) -> np.ndarray:
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    return np.stack([xx / w, yy / h, 0.2 + 0.3 * xx / w - 0.1 * yy / h], axis=-1)


def test_an_interior_hole_in_a_linear_ramp_is_filled_exactly():
    # a linear function is discrete-harmonic: the fill must give it back wherever the unknown
    # region is enclosed by known pixels, whatever the region's shape
    values = _ramp()
    known = np.ones(values.shape[:2], bool)
    known[8:30, 12:45] = False
    known[20:35, 5:10] = False
    garbage = values.copy()
    garbage[~known] = np.random.default_rng(0).random((int((~known).sum()), 3))
    out = harmonic_fill(garbage, known)
    np.testing.assert_allclose(out, values, atol=1e-5)
    assert out.dtype == np.float32


def test_known_pixels_are_kept_and_a_fill_stays_within_its_boundary_values():
    rng = np.random.default_rng(1)
    values = rng.random((30, 40, 3)).astype(np.float32)
    known = rng.random((30, 40)) > 0.5
    known[10:25, 10:30] = False  # one large region, many one-pixel ones
    out = harmonic_fill(values, known)
    np.testing.assert_array_equal(out[known], values[known])
    # maximum principle: a harmonic function takes no value outside its boundary's range
    assert out.min() >= values[known].min() - 1e-6 and out.max() <= values[known].max() + 1e-6
    assert np.isfinite(out).all()


def test_border_regions_are_free_and_nothing_known_leaves_the_values():
    values = np.zeros((10, 12, 1), np.float32)
    values[:, 6:] = 1.0
    known = np.zeros((10, 12), bool)
    known[:, 6] = True  # a known column of ones: everything left of it is a region on the border
    out = harmonic_fill(values, known)
    np.testing.assert_allclose(out[:, :6], 1.0, atol=1e-6)  # Neumann border: the region is constant
    np.testing.assert_array_equal(harmonic_fill(values, np.zeros_like(known)), values)
    with pytest.raises(InputError):
        harmonic_fill(values[..., 0], known)


def _disocclusion(surface_in_gap: bool):
    """A red occluder (depth 1, columns < 20) beside a blue wall (depth 5, columns >= 30) with an
    unseen strip between them: the wall behind the occluder's edge (depth 5) or a hole."""
    h, w = 20, 50
    rgb = np.zeros((1, h, w, 3), np.float32)
    rgb[0, :, :20] = (1.0, 0.0, 0.0)
    rgb[0, :, 30:] = (0.0, 0.0, 1.0)
    rgb[0, :, 20:30] = (0.5, 0.5, 0.5)  # whatever the model smeared there
    depth = np.full((1, h, w), 5.0, np.float32)
    depth[0, :, :20] = 1.0
    alpha = np.ones((1, h, w), np.float32)
    unobserved = np.zeros((1, h, w), np.float32)
    unobserved[0, :, 20:30] = 1.0
    if not surface_in_gap:
        alpha[0, :, 20:30] = 0.0
        depth[0, :, 20:30] = 0.0
    return rgb, unobserved, depth, alpha


@pytest.mark.parametrize("surface_in_gap", [True, False], ids=["unseen wall", "hole"])
def test_a_disocclusion_is_filled_from_the_background(surface_in_gap):
    rgb, unobserved, depth, alpha = _disocclusion(surface_in_gap)
    plain = fill_unobserved(rgb, unobserved)[0, :, 20:30]
    background = fill_unobserved(rgb, unobserved, depth, alpha)[0, :, 20:30]
    blue = np.array([0.0, 0.0, 1.0], np.float32)
    # the plain membrane ramps from the occluder's red to the wall's blue across the strip; with
    # the depth, the occluder's edge (80 % in front) weighs exp(-8) and the strip is the wall's
    assert np.abs(plain - blue).max() > 0.4
    assert np.abs(background - blue).max() < 0.01
    # observed pixels are untouched either way
    full = fill_unobserved(rgb, unobserved, depth, alpha)
    np.testing.assert_array_equal(full[0, :, :20], rgb[0, :, :20])
    np.testing.assert_array_equal(full[0, :, 30:], rgb[0, :, 30:])


def test_background_weights_change_nothing_where_no_boundary_is_in_front():
    rng = np.random.default_rng(3)
    values = rng.random((24, 30, 3)).astype(np.float32)
    known = np.ones((24, 30), bool)
    known[6:18, 8:22] = False
    depth = np.full((24, 30), 2.0)
    depth[~known] = 1.5  # the unseen surface is in front of everything around it
    weights = background_boundary_weights(depth, known, np.ones_like(known))
    np.testing.assert_array_equal(weights, 1.0)
    np.testing.assert_array_equal(harmonic_fill(values, known, weights), harmonic_fill(values, known))
    # nothing unknown, or no depth at all: uniform weights
    np.testing.assert_array_equal(background_boundary_weights(depth, np.ones_like(known), known), 1.0)
    np.testing.assert_array_equal(background_boundary_weights(np.zeros_like(depth), known, known), 1.0)
    with pytest.raises(InputError):
        background_boundary_weights(depth, known, known, tol=0.0)


def test_a_region_walled_in_by_an_occluder_alone_still_takes_its_colour():
    # every boundary pixel is far in front: the weights hit their floor, the system stays solvable
    # and the fill obeys the maximum principle
    values = np.zeros((16, 16, 3), np.float32)
    values[..., 1] = 0.25
    known = np.ones((16, 16), bool)
    known[4:12, 4:12] = False
    depth = np.where(known, 0.1, 10.0)
    weights = background_boundary_weights(depth, known, np.ones_like(known))
    assert weights.min() == pytest.approx(MIN_BOUNDARY_WEIGHT)
    out = harmonic_fill(values + np.where(known, 0.0, 0.9)[..., None], known, weights)
    np.testing.assert_allclose(out[~known], values[~known], atol=1e-5)


def test_depth_and_alpha_go_together():
    rgb, unobserved, depth, alpha = _disocclusion(True)
    with pytest.raises(InputError):
        fill_unobserved(rgb, unobserved, depth, None)
    with pytest.raises(InputError):
        fill_unobserved(rgb, unobserved, depth[:, :5], alpha)


def test_fill_unobserved_blends_by_the_unobserved_weight():
    truth = _ramp()[None]
    render = truth.copy()
    u = np.zeros(truth.shape[:3], np.float32)
    u[0, 10:30, 15:40] = 1.0
    u[0, 10:30, 40:45] = 0.75  # partly observed: three quarters of the fill
    u[0, 5:8, 5:8] = 0.4       # observed (<= 0.5): a boundary pixel, kept
    render[0, 10:30, 15:45] = [0.9, 0.1, 0.1]  # the model's guess where no camera sees: wrong
    out = fill_unobserved(render, u)
    np.testing.assert_allclose(out[0, 10:30, 15:40], truth[0, 10:30, 15:40], atol=1e-5)
    np.testing.assert_allclose(out[0, 10:30, 40:45], 0.25 * render[0, 10:30, 40:45] + 0.75 * truth[0, 10:30, 40:45],
                               atol=1e-5)
    observed = u <= 0.5
    np.testing.assert_array_equal(out[observed], render[observed])
    with pytest.raises(InputError):
        fill_unobserved(render, u[:, :5])


def _request(render: np.ndarray, alpha: np.ndarray, unobserved: np.ndarray) -> RestoreRequest:
    F, H, W, _ = render.shape
    cam = _camera(0.0)
    ref = np.zeros((cam.height, cam.width, 3), np.float32)
    ref_depth, ref_alpha = np.full(ref.shape[:2], 5.0, np.float32), np.ones(ref.shape[:2], np.float32)
    return RestoreRequest(rgb=render, depth=np.full((F, H, W), 5.0, np.float32), alpha=alpha,
                          cameras=[cam] * F, time=0.0, frame=0, ref_images=[ref, ref], ref_cameras=[cam, cam],
                          ref_depths=[ref_depth] * 2, ref_alphas=[ref_alpha] * 2, unobserved=unobserved)


def test_the_gate_falls_back_on_the_fill_and_the_restorer_acts_by_its_confidence():
    truth = _ramp(48, 64)[None]
    render = truth.copy()
    alpha = np.ones(truth.shape[:3], np.float32)
    u = np.zeros(truth.shape[:3], np.float32)
    u[0, 10:20, 10:30] = 1.0   # unobserved solid surface, the render wrong there
    u[0, 25:35, 10:30] = 1.0   # a hole: nothing rendered
    alpha[0, 25:35, 10:30] = 0.0
    render[0, 10:20, 10:30] = 0.0
    render[0, 25:35, 10:30] = 0.0
    restored = np.full_like(render, 0.5)
    conf = np.zeros(u.shape, np.float32)
    conf[0, 10:20, 10:20] = 1.0  # confident on half of the solid region only
    result = RestoreResult(restored, conf, conf.mean(axis=(1, 2)))
    request = _request(render, alpha, u)

    out = gate_restoration(request, result, VisibilityConfig(), fill=True)
    np.testing.assert_allclose(out.rgb[0, 10:20, 10:20], 0.5)                      # trusted restorer
    np.testing.assert_allclose(out.rgb[0, 10:20, 20:30], truth[0, 10:20, 20:30], atol=1e-5)  # fill
    np.testing.assert_allclose(out.rgb[0, 25:35, 10:30], truth[0, 25:35, 10:30], atol=1e-5)  # hole: fill
    observed = u[0] == 0
    np.testing.assert_array_equal(out.rgb[0][observed], render[0][observed])
    np.testing.assert_array_equal(out.confidence, np.maximum(conf * u, u))  # where the target is not the render

    # without the fill: the render where the restorer has no confidence, the restored frame in holes
    plain = gate_restoration(request, result, VisibilityConfig(), fill=False)
    np.testing.assert_array_equal(plain.rgb[0, 10:20, 20:30], render[0, 10:20, 20:30])
    np.testing.assert_allclose(plain.rgb[0, 25:35, 10:30], 0.5)
    # stage2.restore_holes=false: a hole is an unobserved pixel like any other, so where the
    # restorer has no confidence it keeps the render's background colour
    kept = gate_restoration(request, result, VisibilityConfig(), fill=False, restore_holes=False)
    np.testing.assert_array_equal(kept.rgb[0, 25:35, 10:30], render[0, 25:35, 10:30])
    np.testing.assert_allclose(kept.rgb[0, 10:20, 10:20], 0.5)  # the confident restorer still acts
    np.testing.assert_array_equal(kept.confidence, conf * u)


def test_gating_one_frame_of_a_clip_equals_that_frame_of_the_gated_clip():
    from fixer4d.pipeline.restoration import clip_frame

    rng = np.random.default_rng(3)
    render = rng.random((3, 48, 64, 3)).astype(np.float32)
    u = (rng.random((3, 48, 64)) > 0.7).astype(np.float32)
    alpha = rng.random((3, 48, 64)).astype(np.float32)
    conf = rng.random((3, 48, 64)).astype(np.float32)
    result = RestoreResult(rng.random(render.shape).astype(np.float32), conf, conf.mean(axis=(1, 2)))
    request = _request(render, alpha, u)
    for fill in (True, False):
        whole = gate_restoration(request, result, VisibilityConfig(), fill)
        one = gate_restoration(*clip_frame(request, result, 1), VisibilityConfig(), fill)
        np.testing.assert_array_equal(one.rgb[0], whole.rgb[1])
        np.testing.assert_array_equal(one.confidence[0], whole.confidence[1])
