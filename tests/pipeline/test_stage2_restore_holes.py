"""``stage2.restore_holes``: whether a hole in a pseudo-view takes the restored frame whatever the
restorer's confidence, where the gated targets fall back on the render (``stage2.fill_unobserved=false``).
Its default keeps every earlier run's stage keys and checkpoints; the other value changes the key
and, in a refresh, the gated targets only where the render is a hole."""
from __future__ import annotations

import numpy as np

from fixer4d.model.spacetime import SpacetimeGaussians
from fixer4d.pipeline.keys import self_check_key, stage2_key
from fixer4d.pipeline.restoration import make_refresh_callback
from fixer4d.pipeline.run_folder import load_scene_for
from fixer4d.restore.cache import RestoreCache
from fixer4d.train.checkpoints import training_settings
from fixer4d.train.config import STAGE2_SETTINGS_BEFORE, Stage2Config
from pipeline_tiny import tiny_config


def test_the_default_enters_no_key_and_the_other_value_does():
    assert "restore_holes" not in Stage2Config().keyed()
    assert Stage2Config(restore_holes=False).keyed()["restore_holes"] is False
    base = tiny_config(**{"restorer.kind": "warp"})
    off = tiny_config(**{"restorer.kind": "warp", "stage2.restore_holes": False})
    assert stage2_key(off) != stage2_key(base) and self_check_key(off) != self_check_key(base)
    assert training_settings(base.training, base.stage2)["stage2"] == {
        k: v for k, v in base.stage2.to_dict().items() if k not in dict(STAGE2_SETTINGS_BEFORE)}


def test_the_targets_differ_only_in_holes(tmp_path):
    scene = load_scene_for(tiny_config())
    rng = np.random.default_rng(3)
    centre = np.mean([c.center for c in scene.train_cameras], axis=0)
    # a sparse cloud: the pseudo-views have holes between the points
    model = SpacetimeGaussians.from_points(rng.normal(size=(300, 3)) * 0.4 + centre + np.array([0.0, 0.0, 2.0]),
                                           rng.uniform(size=(300, 3)), np.zeros(300), opacity=0.9)
    entries = {}
    for holes in (True, False):
        config = tiny_config(**{"restorer.kind": "warp", "stage2.fill_unobserved": False,
                                "stage2.restore_holes": holes})
        make_refresh_callback(tmp_path / str(holes), scene, config, progress=False)(model, 0)
        entries[holes] = {e.key: e for e in RestoreCache(tmp_path / str(holes) / "cache").entries(0)}
    assert entries[True].keys() == entries[False].keys()
    changed = 0
    for key, on in entries[True].items():
        off = entries[False][key]
        differs = np.any(on.rgb() != off.rgb(), axis=-1)
        hole = on.confidence() > off.confidence()  # the hole rule raised the gate there
        assert not np.any(differs & ~hole)
        changed += int(differs.sum())
    assert changed > 0
