"""Stage 2's gated pseudo-targets (``stage2.pseudo_target = "gated"``) falling back on the render
(``stage2.fill_unobserved=false``, the hole rule on): the cache holds the restored frame only where
the render is a hole or the train cameras leave a pixel unobserved and the restorer is confident,
and the render itself everywhere else. The fill fallback: tests/restore/test_unobserved_fill.py."""
from __future__ import annotations

import numpy as np

from fixer4d.pipeline.config import resolve
from fixer4d.pipeline.restoration import make_refresh_callback, make_request
from fixer4d.restore.base import RestoreResult
from fixer4d.restore.cache import RestoreCache
from fixer4d.restore.visibility import hole_weight
from fixer4d.train.background import resolve_background

MAGENTA = np.array([1.0, 0.0, 1.0], np.float32)
# 8-bit PNG frames in the cache
QUANTUM = 1.0 / 255.0


class Unsure:
    """A restorer that paints everything magenta and trusts none of it (confidence 0)."""

    name = "unsure"

    def settings(self):
        return {}

    def restore(self, request, progress=None):
        rgb = np.broadcast_to(MAGENTA, request.rgb.shape).astype(np.float32)
        conf = np.zeros(request.rgb.shape[:3], np.float32)
        return RestoreResult(rgb, conf, conf.mean(axis=(1, 2)))


def test_gated_targets_keep_the_render_and_fill_its_holes(tmp_path, small_scene, stage1_run):
    model = stage1_run[0].model
    config = resolve("tiny", overrides={"scene.scale": 0.5, "stage2.pseudo_target": "gated", "trajectories.frames": 3,
                                        "trajectories.time_stride": 4, "stage2.fill_unobserved": False})
    refresh = make_refresh_callback(tmp_path, small_scene, config, progress=False, backend="cpu", restorer=Unsure())
    refresh(model, 0)
    entries = RestoreCache(tmp_path / "cache").entries(0)
    assert entries
    holes_seen = 0.0
    for entry in entries:
        pair = tuple(entry.meta["trajectory"]["pair"])
        req = make_request(model, small_scene, entry.cameras, entry.frame, pair, backend="cpu",
                           visibility=config.stage2.visibility,
                           background=resolve_background(config.training.background, small_scene))
        hole = hole_weight(req.alpha, config.stage2.visibility)[..., None]
        expected = req.rgb + hole * (MAGENTA - req.rgb)
        np.testing.assert_allclose(entry.rgb(), np.clip(expected, 0, 1), atol=QUANTUM)
        np.testing.assert_allclose(entry.confidence(), hole[..., 0], atol=1e-3)  # float16 on disk
        holes_seen += float(hole.sum())
    assert holes_seen > 0  # the trajectories do look into holes of the model
