"""Stage 2: pseudo-targets at unseen cameras improve the held-out views, every pseudo-view is
rendered at its clip's time, the cache is refreshed on schedule, resume is exact, and the real
on-disk cache plugs in."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest
import torch

from fixer4d.errors import InputError
from fixer4d.geometry.camera import Camera
from fixer4d.geometry.trajectory import interpolate_pair
from fixer4d.model.spacetime import SpacetimeGaussians
from fixer4d.train.config import Stage2Config
from fixer4d.train.model_init import model_from_clouds
from fixer4d.train.trainer import Trainer

# Pseudo-view positions along each train pair (the restorer's trajectories sample the same).
ALPHAS = (0.25, 0.5, 0.75)


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


def _pairs(scene) -> list[tuple[int, int]]:
    """Neighbouring train cameras along the rig (sorted by camera index)."""
    ids = sorted(scene.train_ids)
    return list(zip(ids, ids[1:]))


def gt_entries(scene, frames=None) -> list[FakeEntry]:
    """Ground-truth pseudo-targets (a perfect restorer) on the pair trajectories, every frame."""
    out = []
    for f in (range(scene.num_frames) if frames is None else frames):
        t = scene.time(f)
        for i, j in _pairs(scene):
            cams = interpolate_pair(scene.cameras[i], scene.cameras[j], ALPHAS)
            rgb = np.stack([scene.render_gt(c, t)[0] for c in cams])
            out.append(FakeEntry(f"t{f:04d}_{i}-{j}", cams, t, rgb, np.ones(rgb.shape[:3], np.float32)))
    return out


def _copy(model: SpacetimeGaussians) -> SpacetimeGaussians:
    return SpacetimeGaussians.from_state_dict(model.state_dict(), model.config)


def test_refinement_with_ground_truth_pseudo_targets_improves_heldout(stage1_run, small_scene, heldout):
    stage1, _, p_stage1 = stage1_run
    cache = FakeCache({0: gt_entries(small_scene)})
    s2 = Stage2Config(refresh_every=100, rounds=1, batch_pseudo=2)
    refiner = Trainer(_copy(stage1.model), small_scene, stage1.config, stage2=s2, cache=cache)
    refiner.train()
    p_stage2 = heldout(small_scene, refiner.render_fn())
    # control: the same number of extra steps without pseudo-views
    control = Trainer(_copy(stage1.model), small_scene, stage1.config,
                      stage2=Stage2Config(refresh_every=100, rounds=1, lambda_gen=0.0), cache=cache)
    control.train()
    p_control = heldout(small_scene, control.render_fn())
    # measured (seed 0): stage 1 19.08 dB, control 18.96 dB (more steps on 4 views overfit them),
    # stage 2 19.18 dB after 100 steps: the gain over the control comes from the pseudo-views
    assert p_stage2 > p_stage1, (p_stage1, p_control, p_stage2)
    assert p_stage2 > p_control + 0.15, (p_stage1, p_control, p_stage2)
    assert all(h["loss"] > 0 for h in refiner.history)


def _small_model(scene, clouds, make_config):
    cfg = make_config(10, init_max_points=400)
    return model_from_clouds(clouds, scene, cfg), cfg


def test_pseudo_views_render_at_their_entry_time_and_refresh_on_schedule(small_scene, small_clouds, make_config,
                                                                          monkeypatch):
    model, cfg = _small_model(small_scene, small_clouds, make_config)
    rounds = {0: gt_entries(small_scene, frames=[1]), 1: gt_entries(small_scene, frames=[3])}
    cache = FakeCache({})
    refreshed = []

    def refresh(m, r):  # the pipeline's callback: "restore" round r with the current model
        assert m is trainer.model
        refreshed.append((trainer.step_count, r))
        cache.rounds[r] = rounds[r]

    s2 = Stage2Config(refresh_every=3, rounds=2, iterations=8, batch_pseudo=2)
    trainer = Trainer(model, small_scene, cfg, stage2=s2, cache=cache, refresh_cache=refresh)
    calls = []
    original = model.at

    def spy(t, camera_center=None):
        calls.append((trainer.round, float(t), None if camera_center is None else np.asarray(camera_center)))
        return original(t, camera_center)

    monkeypatch.setattr(model, "at", spy)
    trainer.train()
    assert refreshed == [(0, 0), (3, 1)]  # steps 0 and 3; no third round at step 6
    centers = {r: [(e.time, c.center) for e in rounds[r] for c in e.cameras] for r in rounds}
    n_pseudo = 0
    for r, t, center in calls:
        if center is None:  # a train view (colour is view-independent): a frame time of the scene
            assert any(t == pytest.approx(small_scene.time(f)) for f in range(small_scene.num_frames))
            continue
        match = [et for et, c in centers[r] if np.allclose(c, center)]
        assert match and all(et == pytest.approx(t) for et in match), (r, t)
        n_pseudo += 1
    assert n_pseudo == 8 * s2.batch_pseudo
    assert {t for r, t, c in calls if c is not None} == {small_scene.time(1), small_scene.time(3)}


def test_stage2_resume_equals_uninterrupted(small_scene, small_clouds, make_config, tmp_path):
    cache = FakeCache({0: gt_entries(small_scene, frames=[0]), 1: gt_entries(small_scene, frames=[2])})
    s2 = Stage2Config(refresh_every=4, rounds=2, iterations=8, densify_until_fraction=0.9)

    def make(run):
        model, cfg = _small_model(small_scene, small_clouds, make_config)
        cfg.checkpoint_every = 6
        cfg.densify_every = 3
        return Trainer(model, small_scene, cfg, run_dir=tmp_path / run, stage2=s2, cache=cache,
                       refresh_cache=lambda m, r: None)

    straight = make("a")
    straight.train()
    make("b").train(6)
    resumed = make("b")
    assert resumed.resume() and resumed.step_count == 6 and resumed.round == 1
    resumed.train()
    for (name, a), (_, b) in zip(straight.model.named_parameters(), resumed.model.named_parameters()):
        assert torch.equal(a, b), name


def test_stage2_needs_a_cache(small_scene, small_clouds, make_config):
    model, cfg = _small_model(small_scene, small_clouds, make_config)
    with pytest.raises(InputError, match="cache"):
        Trainer(model, small_scene, cfg, stage2=Stage2Config())
    trainer = Trainer(model, small_scene, cfg, stage2=Stage2Config(), cache=FakeCache({}))
    with pytest.raises(InputError, match="no entries"):
        trainer.step()


def test_real_restore_cache_plugs_in(small_scene, small_clouds, make_config, tmp_path):
    from fixer4d.restore.base import RestoreRequest, RestoreResult
    from fixer4d.restore.cache import RestoreCache

    model, cfg = _small_model(small_scene, small_clouds, make_config)
    i, j = _pairs(small_scene)[0]
    f = 2
    cams = interpolate_pair(small_scene.cameras[i], small_scene.cameras[j], ALPHAS)
    gt = np.stack([small_scene.render_gt(c, small_scene.time(f))[0] for c in cams])
    h, w = gt.shape[1:3]
    ref = [small_scene.frame(f, i), small_scene.frame(f, j)]
    request = RestoreRequest(rgb=gt, depth=np.ones((3, h, w), np.float32), alpha=np.ones((3, h, w), np.float32),
                             cameras=cams, time=small_scene.time(f), frame=f, ref_images=ref,
                             ref_cameras=[small_scene.cameras[i], small_scene.cameras[j]],
                             ref_depths=[np.ones((h, w), np.float32)] * 2, ref_alphas=[np.ones((h, w), np.float32)] * 2,
                             unobserved=np.full((3, h, w), 0.25, np.float32))
    result = RestoreResult(rgb=gt, confidence=np.full((3, h, w), 0.5, np.float32),
                           frame_confidence=np.full(3, 0.5, np.float32))
    cache = RestoreCache(tmp_path / "cache")
    cache.write(0, RestoreCache.key(f, i, j), request, result, {"step": 0})
    entry = cache.entries(0)[0]
    assert entry.unobserved() == pytest.approx(np.full((3, h, w), 0.25)) and entry.meta["scores"]["unobserved_fraction"] == 0.25
    trainer = Trainer(model, small_scene, cfg, stage2=Stage2Config(refresh_every=3, rounds=1), cache=cache)
    rec = trainer.step()
    assert trainer.round == 0 and rec["loss_gen"] > 0
    # a gated target (the default) carries the confidence itself: every pixel at weight 1
    assert trainer.pseudo.weight(entry) == pytest.approx(np.ones((3, h, w)))
    for target, expected in (("restored", 0.5), ("gated", 1.0)):
        plain = Trainer(model, small_scene, cfg, cache=cache,
                        stage2=Stage2Config(refresh_every=3, rounds=1, pseudo_target=target))
        assert plain.pseudo.weight(entry) == pytest.approx(np.full((3, h, w), expected))
        masked = Trainer(model, small_scene, cfg, cache=cache,
                         stage2=Stage2Config(refresh_every=3, rounds=1, pseudo_target=target, pseudo_mask="unobserved"))
        assert masked.pseudo.weight(entry) == pytest.approx(np.full((3, h, w), 0.25 * expected))
    assert rec["loss"] == pytest.approx(rec["loss_stg"] + 0.5 * rec["loss_gen"], rel=1e-5)
