"""The first segment's static Gaussians in a later segment (fixer4d.pipeline.shared_static): which
own static points they explain, how their rows enter another model config, and the stage-2 swap."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from fixer4d.errors import InputError
from fixer4d.geometry.camera import Camera
from fixer4d.model.spacetime import ModelConfig, SpacetimeGaussians
from fixer4d.pipeline.shared_static import add_shared_static, rows_in, static_rows, swap_shared_static, uncovered


def _wall(x_max: float, z: float = 5.0, config: ModelConfig | None = None) -> SpacetimeGaussians:
    """An opaque wall of static Gaussians in the plane z = ``z``, x in [-3, x_max], y in [-2, 2]."""
    xs, ys = np.meshgrid(np.arange(-3.0, x_max + 1e-9, 0.05), np.arange(-2.0, 2.0 + 1e-9, 0.05))
    pts = np.stack([xs.ravel(), ys.ravel(), np.full(xs.size, z)], 1)
    return SpacetimeGaussians.from_points(pts, np.full_like(pts, 0.5), np.full(len(pts), 0.5), config,
                                          opacity=0.95, scales=np.full(len(pts), 0.05),
                                          dynamic=np.zeros(len(pts), bool))


def _camera() -> Camera:
    return Camera.look_at((0.0, 0.0, 0.0), (0.0, 0.0, 5.0), up=(0.0, -1.0, 0.0), width=64, height=48)


def test_points_the_shared_wall_explains_and_the_ones_it_does_not():
    wall = static_rows(_wall(x_max=0.0))  # covers the left half of the view only
    pts = np.array([[-1.0, 0.0, 5.0],    # on the wall: explained
                    [-1.0, 0.0, 7.0],    # behind it: hidden, no evidence of new content
                    [-1.0, 0.0, 3.0],    # well in front of it: new content
                    [1.0, 0.0, 5.0],     # where the wall is not: new content
                    [0.0, 0.0, -1.0]])   # behind the camera: nobody sees it
    assert uncovered(wall, pts, [_camera()]).tolist() == [False, False, True, True, False]
    assert uncovered(wall, np.zeros((0, 3)), [_camera()]).shape == (0,)


def test_add_keeps_new_own_static_points_and_appends_the_shared_rows_frozen():
    cfg = ModelConfig(motion_degree=1, rotation_velocity=False, temporal_opacity=True, sh_degree=0)
    shared = static_rows(_wall(x_max=0.0, config=cfg))
    own = _wall(x_max=3.0, config=cfg)                 # the same wall, extended to the right
    moving = SpacetimeGaussians.from_points(np.array([[0.0, 0.0, 2.0]]), np.full((1, 3), 0.9), np.array([0.3]), cfg)
    own.append({**moving.tensors(), "frozen": torch.zeros(1, dtype=torch.bool)})
    n_right = int((own.means[:, 0] > 0.2).sum())
    counts = add_shared_static(own, shared, [_camera()])
    assert counts["shared_static"] == shared.num_gaussians
    # the part of the own wall right of the shared one is kept, the part it explains dropped
    # (within a few Gaussian widths of the shared wall's edge its opacity falls below 0.5)
    kept_own = own.means[~own.frozen & ~own.dynamic]
    assert counts["own_static_kept"] == kept_own.shape[0]
    assert int((kept_own[:, 0] > 0.2).sum()) == n_right and bool((kept_own[:, 0] > -0.2).all())
    assert own.num_dynamic == 1 and own.num_frozen == shared.num_gaussians
    assert torch.equal(own.means[own.frozen], shared.means) and not bool(own.dynamic[own.frozen].any())


def test_rows_in_another_config_have_neutral_time_terms_and_the_same_sh_degree():
    shared = static_rows(_wall(x_max=0.0, config=ModelConfig(motion_degree=0, rotation_velocity=False,
                                                              temporal_opacity=False, sh_degree=0)))
    target = ModelConfig(motion_degree=2, rotation_velocity=True, temporal_opacity=True, sh_degree=0)
    rows = rows_in(shared, target)
    assert rows["motion"].shape == (shared.num_gaussians, 6) and not bool(rows["motion"].any())
    assert bool(rows["frozen"].all()) and not bool(rows["dynamic"].any())
    with pytest.raises(InputError, match="SH degree"):
        rows_in(shared, ModelConfig(sh_degree=1))


def test_swap_replaces_only_the_frozen_rows():
    model = _wall(x_max=1.0)
    model.append(rows_in(static_rows(_wall(x_max=0.0)), model.config))
    refined = static_rows(_wall(x_max=-1.0))
    out = swap_shared_static(model, refined)
    assert out.num_frozen == refined.num_gaussians and torch.equal(out.means[out.frozen], refined.means)
    assert torch.equal(out.means[~out.frozen], model.means[~model.frozen])
    assert model.num_frozen != out.num_frozen  # the input model is left as it was
