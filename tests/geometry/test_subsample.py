"""The init subsample: the random draw as it always was, the spatial one even and seed-free."""
import numpy as np
import pytest
import torch

from fixer4d.errors import InputError
from fixer4d.geometry.subsample import spatial_subsample, subsample
from fixer4d.model import terms as E
from fixer4d.train.checkpoints import result_settings
from fixer4d.train.config import TrainingConfig
from tests.model.test_terms import _init


def _cluster_and_room(seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """20000 points in a ball of radius 0.1 at the origin, 2000 spread over a 10 m box; (points,
    mask of the spread ones)."""
    rng = np.random.default_rng(seed)
    ball = rng.normal(size=(20000, 3)) * 0.03
    room = rng.uniform(-5.0, 5.0, size=(2000, 3))
    return np.concatenate([ball, room]), np.r_[np.zeros(20000, bool), np.ones(2000, bool)]


def test_random_is_the_seeded_uniform_draw():
    pts, _ = _cluster_and_room()
    got = subsample(pts, 500, "random", np.random.default_rng(4))
    assert np.array_equal(got, np.sort(np.random.default_rng(4).choice(len(pts), size=500, replace=False)))


def test_spatial_keeps_k_distinct_points_whatever_the_seed():
    pts, _ = _cluster_and_room()
    a = subsample(pts, 1000, "spatial", np.random.default_rng(0))
    b = subsample(pts, 1000, "spatial", np.random.default_rng(99))
    assert np.array_equal(a, b)
    assert a.size == 1000 and np.unique(a).size == 1000 and np.all(np.diff(a) > 0)


def test_spatial_reaches_the_sparse_region_a_random_draw_starves():
    pts, spread = _cluster_and_room()
    rand = subsample(pts, 1000, "random", np.random.default_rng(0))
    even = spatial_subsample(pts, 1000)
    assert spread[rand].mean() < 0.15  # ~2000 / 22000 of the draw
    assert spread[even].mean() > 0.6  # the ball is a few cells; the room gets the rest
    # the kept spread points cover the room: every octant keeps some
    octant = (pts[even][spread[even]] > 0) @ np.array([1, 2, 4])
    assert np.bincount(octant, minlength=8).min() > 20


def test_groups_never_share_a_cell():
    rng = np.random.default_rng(1)
    p = rng.uniform(size=(300, 3))
    pts = np.concatenate([p, p])  # two frames, the same places
    groups = np.r_[np.zeros(300, int), np.ones(300, int)]
    keep = spatial_subsample(pts, 200, groups)
    assert keep.size == 200
    assert 60 < int((groups[keep] == 0).sum()) < 140  # both frames keep points


def test_duplicates_and_degenerate_clouds_still_give_k():
    pts = np.repeat(np.eye(3), 100, axis=0)  # 3 distinct places, 300 points
    keep = spatial_subsample(pts, 50)
    assert keep.size == 50 and np.unique(keep).size == 50
    same = np.zeros((40, 3))
    assert np.array_equal(spatial_subsample(same, 10), np.arange(10))
    assert subsample(same, 100, "spatial", np.random.default_rng(0)).size == 40
    assert subsample(same, 0, "spatial", np.random.default_rng(0)).size == 0


def test_unknown_method_and_config_value_raise():
    with pytest.raises(ValueError, match="choose one of"):
        subsample(np.zeros((5, 3)), 2, "voxel", np.random.default_rng(0))
    with pytest.raises(InputError, match="init_subsample"):
        TrainingConfig(init_subsample="voxel")


def test_spatial_init_is_the_same_model_for_every_seed():
    init = _init(n_dyn=400, degree=2, rotating=0.3, seed=3)
    dec = E.decide_terms(init)
    a = E.model_from_decomposed(init, dec, opacity=0.1, max_points=300, seed=1, subsample_method="spatial")
    b = E.model_from_decomposed(init, dec, opacity=0.1, max_points=300, seed=2, subsample_method="spatial")
    assert a.num_gaussians == 300
    for k, v in a.tensors().items():
        assert torch.equal(v, b.tensors()[k]), k
    c = E.model_from_decomposed(init, dec, opacity=0.1, max_points=300, seed=1)
    d = E.model_from_decomposed(init, dec, opacity=0.1, max_points=300, seed=2)
    assert not torch.equal(c.means, d.means)


def test_the_random_subsample_leaves_the_stage_keys_as_they_were():
    assert "init_subsample" not in result_settings(TrainingConfig().to_dict())
    assert result_settings(TrainingConfig(init_subsample="spatial").to_dict())["init_subsample"] == "spatial"
