"""The init subsample: the random draw as it always was, the stratified one keeping each region's
share whatever the seed, the spatial one even and seed-free."""
import numpy as np
import pytest
import torch

from fixer4d.errors import InputError
from fixer4d.geometry.subsample import morton_keys, spatial_subsample, stratified_subsample, subsample
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


def test_stratified_keeps_each_regions_share_where_the_random_draw_varies():
    pts, spread = _cluster_and_room()
    region = (pts > 0) @ np.array([1, 2, 4]) + 8 * spread  # 16 regions: ball or room, by octant
    def counts(method: str) -> np.ndarray:  # (20 seeds, 16 regions) kept points per region
        return np.array([np.bincount(region[subsample(pts, 1000, method, np.random.default_rng(s))], minlength=16)
                         for s in range(20)])
    strat, rand = counts("stratified"), counts("random")
    # the same mean share (both keep the density), a fraction of the spread over seeds: only the
    # runs a region's boundary cuts vary (many where the octant planes cut the dense ball)
    assert np.allclose(strat.mean(axis=0), rand.mean(axis=0), rtol=0.1, atol=1.5)
    ratio = strat.std(axis=0) / rand.std(axis=0)
    assert ratio.max() < 0.65 and ratio.mean() < 0.45
    assert strat[:, 8:].sum(axis=1).std() < 0.3 * rand[:, 8:].sum(axis=1).std()  # room against ball
    a, b = (stratified_subsample(pts, 1000, np.random.default_rng(s)) for s in (0, 1))
    assert a.size == b.size == 1000 and np.unique(a).size == 1000 and np.all(np.diff(a) > 0)
    assert not np.array_equal(a, b)  # the seed still picks the points inside each run


def test_stratified_edge_cases():
    same = np.zeros((40, 3))
    assert np.array_equal(morton_keys(same), np.zeros(40, np.int64))
    keep = subsample(same, 10, "stratified", np.random.default_rng(0))
    assert keep.size == 10 and np.unique(keep).size == 10
    assert subsample(same, 100, "stratified", np.random.default_rng(0)).size == 40
    line = np.c_[np.linspace(0.0, 1.0, 101), np.zeros(101), np.zeros(101)]
    assert np.all(np.diff(morton_keys(line)) > 0)  # one axis: the key is the cell index's order
    keep = stratified_subsample(line, 10, np.random.default_rng(3))
    assert np.all(np.diff(keep) >= 1) and np.all(keep // 10 == np.arange(10))  # one per tenth
    two = np.concatenate([line, line])  # two frames: each keeps its share
    groups = np.r_[np.zeros(101, int), np.ones(101, int)]
    keep = stratified_subsample(two, 20, np.random.default_rng(3), groups)
    assert int((groups[keep] == 0).sum()) == 10


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
