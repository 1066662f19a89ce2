"""Stage 2 as the paper states it: L = mean over observed views of L_STG + lambda_gen x mean over
pseudo-views of the confidence-weighted L1, and pseudo-views never at the train cameras themselves."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest
import torch

from fixer4d.geometry.camera import Camera
from fixer4d.geometry.trajectory import interpolate_pair
from fixer4d.train import trainer as trainer_module
from fixer4d.train.config import Stage2Config
from fixer4d.train.model_init import model_from_clouds
from fixer4d.train.trainer import Trainer



@dataclass
class FakeEntry:
    key: str
    cameras: list[Camera]
    time: float
    frames: np.ndarray
    conf: np.ndarray

    def rgb(self) -> np.ndarray:
        return self.frames

    def confidence(self) -> np.ndarray:
        return self.conf

    def unobserved(self) -> np.ndarray:
        """Every pixel unobserved: the pseudo-loss acts everywhere, as with pseudo_mask=all."""
        return np.ones_like(self.conf)


class FakeCache:
    """In-memory stand-in for RestoreCache: round -> entries."""

    def __init__(self, rounds: dict[int, list[FakeEntry]]) -> None:
        self.rounds = rounds

    def entries(self, round: int | None = None) -> list[FakeEntry]:
        return list(self.rounds.get(self.latest_round() if round is None else round, []))

    def latest_round(self) -> int | None:
        return max(self.rounds) if self.rounds else None


def _model(scene, clouds, make_config, **overrides):
    cfg = make_config(10, init_max_points=400, **overrides)
    return model_from_clouds(clouds, scene, cfg), cfg


def _endpoint_clip(scene, frame: int = 1, conf: float = 1.0, nan_endpoints: bool = True) -> FakeEntry:
    """A 3-frame pair clip (alpha 0, 0.5, 1): its endpoints ARE train cameras. Their targets are NaN
    when ``nan_endpoints``, so a pseudo loss that used them would not be finite."""
    i, j = sorted(scene.train_ids)[:2]
    cams = interpolate_pair(scene.cameras[i], scene.cameras[j], np.array([0.0, 0.5, 1.0]))
    frames = np.stack([scene.render_gt(c, scene.time(frame))[0] for c in cams]).astype(np.float32)
    if nan_endpoints:
        frames[0] = np.nan
        frames[2] = np.nan
    h, w = frames.shape[1:3]
    return FakeEntry(f"t{frame:04d}_{i}-{j}", cams, scene.time(frame), frames, np.full((3, h, w), conf, np.float32))


def test_observed_loss_is_a_per_view_mean(small_scene, small_clouds, make_config, monkeypatch):
    # every view's L_STG is made exactly 1: a sum over the 2 views of a step would report 2
    monkeypatch.setattr(trainer_module, "stg_loss", lambda render, target, weight=None: (render * 0.0).sum() + 1.0)
    model, cfg = _model(small_scene, small_clouds, make_config, views_per_step=2)
    rec = Trainer(model, small_scene, cfg).step()
    assert rec["loss_stg"] == pytest.approx(1.0)
    model, cfg = _model(small_scene, small_clouds, make_config, views_per_step=2)
    trainer = Trainer(model, small_scene, cfg, stage2=Stage2Config(refresh_every=5, rounds=1, lambda_gen=0.5),
                      cache=FakeCache({0: [_endpoint_clip(small_scene, nan_endpoints=False)]}))
    rec = trainer.step()
    assert rec["loss_stg"] == pytest.approx(1.0)
    assert rec["loss"] == pytest.approx(1.0 + 0.5 * rec["loss_gen"], rel=1e-6)


def test_pseudo_views_skip_the_train_cameras(small_scene, small_clouds, make_config):
    model, cfg = _model(small_scene, small_clouds, make_config)
    trainer = Trainer(model, small_scene, cfg, stage2=Stage2Config(refresh_every=20, rounds=1, batch_pseudo=2),
                      cache=FakeCache({0: [_endpoint_clip(small_scene)]}))
    for _ in range(8):  # 16 picks: with the endpoints in the pool one would be drawn (p = 1 - (1/3)^16)
        rec = trainer.step()
        assert np.isfinite(rec["loss"]) and rec["loss_gen"] > 0
    assert [list(f) for f in trainer.pseudo.entry_frames] == [[1]]


def test_a_round_of_endpoints_only_is_refused(small_scene, small_clouds, make_config):
    from fixer4d.errors import InputError

    model, cfg = _model(small_scene, small_clouds, make_config)
    entry = _endpoint_clip(small_scene)
    only_ends = FakeEntry(entry.key, [entry.cameras[0], entry.cameras[2]], entry.time, entry.frames[[0, 2]],
                          entry.conf[[0, 2]])
    trainer = Trainer(model, small_scene, cfg, stage2=Stage2Config(refresh_every=5, rounds=1),
                      cache=FakeCache({0: [only_ends]}))
    with pytest.raises(InputError, match="novel views"):
        trainer.step()


def test_confidence_weights_the_pseudo_loss(small_scene, small_clouds, make_config):
    losses = []
    for conf in (1.0, 0.25, 0.0):
        model, cfg = _model(small_scene, small_clouds, make_config)
        trainer = Trainer(model, small_scene, cfg, stage2=Stage2Config(refresh_every=5, rounds=1, pseudo_target="restored"),
                          cache=FakeCache({0: [_endpoint_clip(small_scene, conf=conf)]}))
        torch.manual_seed(0)
        losses.append(trainer.step()["loss_gen"])
    assert losses[0] > 0
    assert losses[1] == pytest.approx(0.25 * losses[0], rel=1e-5)
    assert losses[2] == 0.0


@dataclass
class MaskedEntry(FakeEntry):
    hidden: np.ndarray | None = None

    def unobserved(self) -> np.ndarray | None:
        return self.hidden


def _masked_clip(scene) -> MaskedEntry:
    base = _endpoint_clip(scene, conf=0.8, nan_endpoints=False)
    rng = np.random.default_rng(0)
    hidden = rng.random(base.conf.shape).astype(np.float32)
    return MaskedEntry(base.key, base.cameras, base.time, base.frames, base.conf, hidden)


def _pseudo_weight(scene, clouds, make_config, entry, **stage2):
    model, cfg = _model(scene, clouds, make_config)
    trainer = Trainer(model, scene, cfg, stage2=Stage2Config(refresh_every=5, rounds=1, **stage2),
                      cache=FakeCache({0: [entry]}))
    return trainer.pseudo.weight(entry)


def _paper_stage2() -> dict:
    """The Stage2Config fields of ``--paper-stage2`` (pipeline.config.PAPER_STAGE2)."""
    from fixer4d.pipeline.config import PAPER_STAGE2

    return {k.split(".", 1)[1]: v for k, v in PAPER_STAGE2.items() if k.startswith("stage2.")}


def test_paper_switch_gives_the_confidence_weighted_loss_exactly(small_scene, small_clouds, make_config):
    # --paper-stage2: the weight is the restorer's confidence, bit for bit (the paper's stage 2,
    # with the unobserved map ignored even where the cache has one)
    entry = _masked_clip(small_scene)
    paper = _paper_stage2()
    assert paper == {"pseudo_target": "restored", "pseudo_mask": "all", "densify_stats": "all"}
    w = _pseudo_weight(small_scene, small_clouds, make_config, entry, **paper)
    assert np.array_equal(w, entry.conf)
    w = _pseudo_weight(small_scene, small_clouds, make_config, entry, **paper, confidence_weighting=False)
    assert np.array_equal(w, np.ones_like(entry.conf))


def test_unobserved_mask_weights_the_pseudo_loss(small_scene, small_clouds, make_config):
    entry = _masked_clip(small_scene)
    w = _pseudo_weight(small_scene, small_clouds, make_config, entry, pseudo_mask="unobserved", pseudo_target="restored")
    np.testing.assert_allclose(w, entry.conf * entry.hidden, rtol=1e-6)
    w = _pseudo_weight(small_scene, small_clouds, make_config, entry, pseudo_mask="unobserved", observed_weight=0.25,
                       pseudo_target="restored")
    np.testing.assert_allclose(w, entry.conf * (0.25 + 0.75 * entry.hidden), rtol=1e-6)
    blank = MaskedEntry(entry.key, entry.cameras, entry.time, entry.frames, entry.conf, None)
    with pytest.raises(Exception, match="unobserved-pixel map"):
        _pseudo_weight(small_scene, small_clouds, make_config, blank, pseudo_mask="unobserved")
    # the default (chosen on the validation cameras) supervises every pixel of a gated target
    assert np.array_equal(_pseudo_weight(small_scene, small_clouds, make_config, entry), np.ones_like(entry.conf))


def test_a_gated_target_weighs_every_pixel_alike(small_scene, small_clouds, make_config):
    # the gated target carries the confidence itself (the render stands where it is low), so its
    # loss weight is 1 everywhere; with pseudo_mask=unobserved the unobserved map still applies
    entry = _masked_clip(small_scene)
    w = _pseudo_weight(small_scene, small_clouds, make_config, entry, pseudo_target="gated")
    assert np.array_equal(w, np.ones_like(entry.conf))
    w = _pseudo_weight(small_scene, small_clouds, make_config, entry, pseudo_target="gated", pseudo_mask="unobserved")
    np.testing.assert_allclose(w, entry.hidden, rtol=1e-6)
    with pytest.raises(Exception, match="pseudo_target"):
        Stage2Config(pseudo_target="render")
