"""Stage 2's densification evidence (``Stage2Config.densify_stats``): which renders' screen-space
gradients reach the densification statistics: every render ("all"), the observed views only
("observed"), or the observed views plus the pseudo-views' gradient of their loss over the pixels
no train camera explains ("evidence")."""
from __future__ import annotations

import numpy as np
import pytest
import torch

from fixer4d.errors import InputError
from fixer4d.train.config import Stage2Config
from fixer4d.train.trainer import Trainer

from tests.train.test_stage2_loss import FakeCache, FakeEntry, _endpoint_clip, _model

VIEWS = 2


class HiddenEntry(FakeEntry):
    """A clip whose unobserved-pixel map is given (F, H, W); None = a cache without the map."""

    hidden: np.ndarray | None = None

    def unobserved(self):
        return self.hidden


def _entry(scene, hidden_value: float | None) -> HiddenEntry:
    base = _endpoint_clip(scene, nan_endpoints=False)
    entry = HiddenEntry(base.key, base.cameras, base.time, base.frames, base.conf)
    entry.hidden = None if hidden_value is None else np.full_like(base.conf, hidden_value)
    return entry


def _first_step_updates(scene, clouds, make_config, densify_stats: str, hidden_value: float | None = 1.0):
    """The (gradient, width) of every densification-statistics update of a trainer's first stage-2
    step (the densification window covers it)."""
    model, cfg = _model(scene, clouds, make_config, views_per_step=VIEWS)
    s2 = Stage2Config(refresh_every=20, rounds=1, lambda_gen=0.5, densify_until_fraction=1.0,
                      densify_stats=densify_stats)
    trainer = Trainer(model, scene, cfg, stage2=s2, cache=FakeCache({0: [_entry(scene, hidden_value)]}))
    seen = []
    update = trainer.stats.update
    trainer.stats.update = lambda grad, drawn, w, h: (seen.append(grad.detach().clone()), update(grad, drawn, w, h))
    trainer.step()
    return seen


def test_all_counts_every_render_observed_counts_the_views_only(small_scene, small_clouds, make_config):
    every = _first_step_updates(small_scene, small_clouds, make_config, "all")
    observed = _first_step_updates(small_scene, small_clouds, make_config, "observed")
    assert len(every) == VIEWS + 1 and len(observed) == VIEWS
    for a, b in zip(every[:VIEWS], observed):  # the same observed gradients, bit for bit
        assert torch.equal(a, b)
    assert float(every[-1].abs().sum()) > 0.0  # the pseudo-view's gradient is real


def test_evidence_is_the_pseudo_gradient_over_unobserved_pixels(small_scene, small_clouds, make_config):
    every = _first_step_updates(small_scene, small_clouds, make_config, "all")
    # every pixel unobserved: the evidence gradient is the full pseudo gradient
    hidden = _first_step_updates(small_scene, small_clouds, make_config, "evidence", hidden_value=1.0)
    assert len(hidden) == VIEWS + 1
    torch.testing.assert_close(hidden[-1], every[-1], rtol=1e-5, atol=1e-9)
    # every pixel observed: the pseudo-view adds nothing
    seen = _first_step_updates(small_scene, small_clouds, make_config, "evidence", hidden_value=0.0)
    assert float(seen[-1].abs().max()) == 0.0
    # half-unobserved everywhere: half the gradient (the loss is linear in the weight)
    half = _first_step_updates(small_scene, small_clouds, make_config, "evidence", hidden_value=0.5)
    torch.testing.assert_close(half[-1], 0.5 * every[-1], rtol=1e-5, atol=1e-9)


def test_evidence_needs_the_unobserved_map(small_scene, small_clouds, make_config):
    with pytest.raises(InputError, match="unobserved-pixel map"):
        _first_step_updates(small_scene, small_clouds, make_config, "evidence", hidden_value=None)


def test_densify_stats_is_validated():
    with pytest.raises(InputError, match="densify_stats"):
        Stage2Config(densify_stats="pseudo")
