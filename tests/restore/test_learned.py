"""The learned restorer: it repairs a degraded render of a scene with known truth by a clear
margin, trains deterministically, saves plain arrays that load back, and is a Restorer."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from fixer4d.bench.restore import clip_psnr, make_request
from fixer4d.errors import InputError
from fixer4d.restore.base import Restorer
from fixer4d.restore.config import WEIGHTS_FILE, LearnedRestorerConfig, RestoreConfig
from fixer4d.restore.factory import build_restorer
from fixer4d.restore.learned import (FEATURE_CHANNELS, LearnedRestorer, RestorerNet, request_features,
                                     restore_features, train_network)
from fixer4d.restore.reference_warp import ReferenceWarpRestorer

SIZE = (96, 72)
FRAMES = 5
# A short training: enough to move off the warp restorer's output, seconds on one core.
CONFIG = LearnedRestorerConfig(steps=60, batch=2, crop=40, threads=1)


@pytest.fixture(scope="module")
def pairs():
    """Training samples from the rig pair 0-1 and an unseen test clip on pair 1-2 (2% wrong depth
    everywhere, like a model's geometry), with its truth."""
    warp = ReferenceWarpRestorer()
    train_req, train_gt = make_request(*SIZE, FRAMES, pair=(0, 1), seed=1, depth_noise=0.02)
    feats, _ = request_features(train_req, warp)
    test_req, test_gt = make_request(*SIZE, FRAMES, pair=(1, 2), seed=2, depth_noise=0.02)
    return list(zip(feats, train_gt)), test_req, test_gt


@pytest.fixture(scope="module")
def trained(pairs):
    before = torch.get_num_threads()
    try:
        return train_network(pairs[0], CONFIG)
    finally:
        torch.set_num_threads(before)


def test_network_is_small():
    assert RestorerNet().num_parameters() < 1_000_000


def test_restores_an_unseen_clip_by_a_clear_margin(pairs, trained):
    _, test_req, test_gt = pairs
    net, stats = trained
    restorer = LearnedRestorer(net, RestoreConfig(kind="learned", learned=CONFIG))
    assert isinstance(restorer, Restorer)
    result = restorer.restore(test_req)
    render = clip_psnr(np.clip(test_req.rgb, 0, 1), test_gt)
    restored = clip_psnr(result.rgb, test_gt)
    assert restored > render + 8.0, (render, restored)
    assert result.confidence.min() >= 0.0 and result.confidence.max() <= 1.0
    assert np.isfinite(stats["final_loss"]) and stats["cpu_seconds"] > 0


def test_training_is_deterministic(pairs, trained):
    net_b, _ = train_network(pairs[0], CONFIG)
    for (name, a), b in zip(trained[0].state_dict().items(), net_b.state_dict().values()):
        assert torch.equal(a, b), name


def test_training_lowers_the_error_on_its_pairs(pairs, trained):
    net, _ = trained
    untrained = RestorerNet(CONFIG.width, CONFIG.residual_bound)
    def err(n):
        return np.mean([np.abs(restore_features(n, f)[0] - g).mean() for f, g in pairs[0]])
    assert err(net) < err(untrained)


def test_weights_round_trip(tmp_path, pairs, trained):
    net, _ = trained
    cfg = RestoreConfig(kind="learned", learned=CONFIG)
    LearnedRestorer(net, cfg).save(tmp_path)
    with np.load(tmp_path / WEIGHTS_FILE, allow_pickle=False) as data:  # plain arrays, no pickles
        assert all(data[k].dtype == np.float32 for k in data.files)
    loaded = build_restorer(cfg, tmp_path)
    feats = pairs[0][0][0]
    assert feats.shape[0] == FEATURE_CHANNELS
    np.testing.assert_array_equal(restore_features(loaded.net, feats)[0], restore_features(net, feats)[0])
    assert loaded.settings()["weights_sha1"] == LearnedRestorer.load(tmp_path, cfg).meta["weights_sha1"]
    (tmp_path / WEIGHTS_FILE).write_bytes(b"not an npz")
    with pytest.raises(InputError, match="unreadable"):
        LearnedRestorer.load(tmp_path, cfg)


def test_no_pairs_is_a_clear_error():
    with pytest.raises(InputError, match="no training pairs"):
        train_network([], CONFIG)
