"""The undetermined map: per-pixel disagreement of two fields' renders (restore.undetermined)."""
from __future__ import annotations

import numpy as np
import pytest

from fixer4d.errors import InputError
from fixer4d.restore.undetermined import combined_weight, undetermined_map

H, W = 40, 50


def _render(seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    return rng.random((H, W, 3), dtype=np.float32), rng.random((H, W), dtype=np.float32)


def test_identical_renders_give_an_all_zero_map():
    rgb, alpha = _render(0)
    out = undetermined_map(rgb, rgb.copy(), alpha, alpha.copy())
    assert out.shape == (H, W) and out.dtype == np.float32
    assert not out.any()


def test_a_region_one_field_lacks_is_undetermined_and_the_rest_is_not():
    rgb, alpha = _render(1)
    rgb_b, alpha_b = rgb.copy(), alpha.copy()
    rgb_b[10:25, 10:30] = 0.0  # field B renders nothing there: background colour, no coverage
    alpha_b[10:25, 10:30] = 0.0
    out = undetermined_map(rgb, rgb_b, alpha, alpha_b)
    assert out[13:22, 13:27].min() > 0.9
    assert out[:5].max() == 0.0 and out[:, 35:].max() == 0.0
    assert 0.0 <= out.min() and out.max() <= 1.0


def test_a_single_pixel_difference_does_not_count():
    rgb, alpha = _render(2)
    rgb_b, alpha_b = rgb.copy(), alpha.copy()
    rgb_b[20, 20] = 1.0 - rgb_b[20, 20]
    alpha_b[20, 20] = 1.0 - alpha_b[20, 20]
    assert not undetermined_map(rgb, rgb_b, alpha, alpha_b).any()


def test_a_colour_only_difference_counts_without_a_coverage_difference():
    rgb, alpha = _render(3)
    rgb_b = rgb.copy()
    rgb_b[5:20, 5:20] = (rgb_b[5:20, 5:20] + 0.5) % 1.0  # every channel off by 0.5
    out = undetermined_map(rgb, rgb_b, alpha, alpha)
    assert out[8:17, 8:17].min() == pytest.approx(1.0)


def test_shapes_are_checked():
    rgb, alpha = _render(4)
    with pytest.raises(InputError):
        undetermined_map(rgb, rgb[:-1], alpha, alpha)
    with pytest.raises(InputError):
        undetermined_map(rgb, rgb, alpha, alpha, window=4)


def test_the_combined_weight_is_either_map_or_their_max():
    vis = np.array([[0.0, 0.7], [1.0, 0.2]], np.float32)
    und = np.array([[0.5, 0.1], [0.0, 0.9]], np.float32)
    np.testing.assert_array_equal(combined_weight(vis, und, "visibility"), vis)
    np.testing.assert_array_equal(combined_weight(vis, und, "undetermined"), und)
    np.testing.assert_array_equal(combined_weight(vis, und, "max"),
                                  np.array([[0.5, 0.7], [1.0, 0.9]], np.float32))
    with pytest.raises(InputError):
        combined_weight(vis, und, "mean")
