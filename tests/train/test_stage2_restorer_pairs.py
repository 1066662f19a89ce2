"""The learned restorer's pair builder: leave-one-camera-out pairs from train cameras only, a
held-back validation fold, resumable outputs."""
from __future__ import annotations

import json

import numpy as np
import pytest

from fixer4d.restore.config import VALIDATION_FILE, WEIGHTS_FILE, LearnedRestorerConfig, RestoreConfig
from fixer4d.restore.learned import LearnedRestorer
from fixer4d.scene.train_view import HeldOutAccess, TrainOnlyView
from fixer4d.train.restorer_pairs import build_fold, pair_frames, train_scene_restorer

# The smallest run that exercises every part: 10-iteration leave-one-out trainings, 2 timestamps.
TINY = LearnedRestorerConfig(loo_iterations=10, loo_scale=1.0, pair_frames=2, steps=4, batch=2, crop=16)


class GuardedScene:
    """A scene that records every camera whose frames are read and refuses held-out ones."""

    def __init__(self, base) -> None:
        self._base = base
        self.read: set[int] = set()

    def __getattr__(self, name):
        return getattr(self._base, name)

    def frame(self, frame: int, cam: int):
        self.read.add(cam)
        if cam not in self._base.train_ids:
            raise AssertionError(f"held-out camera {cam} was read")
        return self._base.frame(frame, cam)


def test_pairs_come_from_train_cameras_only(small_scene, small_clouds, make_config, tmp_path):
    scene = GuardedScene(small_scene)
    cfg = RestoreConfig(kind="learned", learned=TINY)
    restorer = train_scene_restorer(scene, small_clouds, make_config(10), tmp_path, cfg, progress=False)
    assert scene.read and scene.read <= set(small_scene.train_ids)
    assert isinstance(restorer, LearnedRestorer)
    val = json.loads((tmp_path / VALIDATION_FILE).read_text())
    held = small_scene.train_ids[TINY.validation_fold]
    assert val["held_out_fold_camera"] == held
    assert val["validation_pairs"] == len(pair_frames(small_scene.num_frames, TINY.pair_frames))
    assert np.isfinite(val["gain_db"]) and val["cpu_seconds"]["total"] > 0
    for cam in small_scene.train_ids:  # every fold's pairs: train cameras, the left-out one is the LOO target
        with np.load(tmp_path / "pairs" / f"fold_{cam}.npz") as fold:
            assert set(fold["cams"].tolist()) <= set(small_scene.train_ids)
            assert set(fold["cams"][fold["loo"]].tolist()) == {cam}
            assert cam not in set(fold["cams"][~fold["loo"]].tolist())
    # resume: finished weights with the same settings are loaded, nothing is read again
    scene.read.clear()
    again = train_scene_restorer(scene, small_clouds, make_config(10), tmp_path, cfg, progress=False)
    assert not scene.read and again.meta["weights_sha1"] == restorer.meta["weights_sha1"]
    assert (tmp_path / WEIGHTS_FILE).is_file()


def test_the_pair_scene_refuses_held_out_cameras(small_scene):
    views = TrainOnlyView(small_scene, small_scene.train_ids[:3], 0.5)
    assert views.test_ids == [] and views.train_ids == small_scene.train_ids[:3]
    views.frame(0, small_scene.train_ids[3])  # a train camera outside the fold may be a reference
    for read in (views.frame, views.mask, views.depth):
        with pytest.raises(HeldOutAccess, match="not a train camera"):
            read(0, small_scene.test_ids[0])
    with pytest.raises(Exception, match="not train cameras"):
        TrainOnlyView(small_scene, [small_scene.test_ids[0]], 1.0)


def test_a_fold_must_leave_out_a_train_camera(small_scene, small_clouds, make_config):
    with pytest.raises(Exception, match="not a train camera"):
        build_fold(small_scene, small_clouds, make_config(10), small_scene.test_ids[0],
                   RestoreConfig(kind="learned", learned=TINY))


def test_the_stage1_model_adds_its_train_camera_renders(small_scene, small_clouds, make_config, tmp_path):
    from fixer4d.train.model_init import model_from_clouds

    scene = GuardedScene(small_scene)
    cfg = RestoreConfig(kind="learned", learned=TINY)
    train_scene_restorer(scene, small_clouds, make_config(10), tmp_path, cfg, progress=False)
    plain = json.loads((tmp_path / VALIDATION_FILE).read_text())["training_pairs"]
    model = model_from_clouds(small_clouds, small_scene, make_config(10))
    scene.read.clear()
    train_scene_restorer(scene, small_clouds, make_config(10), tmp_path, cfg, progress=False, model=model)
    assert scene.read <= set(small_scene.train_ids)
    frames = len(pair_frames(small_scene.num_frames, TINY.pair_frames))
    # every train camera but the held-back one, at every pair timestamp; the folds were reused
    val = json.loads((tmp_path / VALIDATION_FILE).read_text())
    assert val["training_pairs"] == plain + (len(small_scene.train_ids) - 1) * frames
