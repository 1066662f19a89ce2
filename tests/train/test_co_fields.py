"""Two stage-1 fields that prune each other (train.co_fields) and their undetermined map."""
from __future__ import annotations

import pytest
import torch

from tests.train.conftest import small_config

ITERATIONS = 120


def _trainer(scene, clouds, config, run_dir=None):
    from fixer4d.train.model_init import model_from_clouds
    from fixer4d.train.trainer import Trainer

    return Trainer(model_from_clouds(clouds, scene, config), scene, config, run_dir=run_dir)


def _co(scene, clouds, run_dir=None, **co):
    from fixer4d.train.co_fields import CoFields, twin_trainer
    from fixer4d.train.co_fields_config import CoFieldsConfig

    a = _trainer(scene, clouds, small_config(ITERATIONS), run_dir)
    return CoFields(a, twin_trainer(a, None, run_dir), CoFieldsConfig(enabled=True, prune_every=2, **co))


def test_co_pruning_removes_an_isolated_gaussian_and_keeps_matched_ones(small_scene, small_clouds):
    from fixer4d.train.co_fields import co_prune

    co = _co(small_scene, small_clouds)
    a, b = co.a, co.b
    n = a.model.num_gaussians
    with torch.no_grad():
        a.model.means[0] += 10.0 * a.extent  # far from everything of field B
    counts = co_prune(a, b, 0.02)
    assert counts == {"pruned_a": 1, "pruned_b": 0}
    assert a.model.num_gaussians == n - 1 and b.model.num_gaussians == n
    assert float(a.model.means.detach().abs().max()) < 5.0 * a.extent
    # the optimizer's state and the statistics follow the rows: a step runs
    assert len(a.stats) == n - 1
    a.step()
    state = a.optimizer.state[a.optimizer.param_groups[0]["params"][0]]
    assert state["exp_avg"].shape[0] == a.model.num_gaussians


def test_identical_seeds_give_identical_fields_and_an_all_zero_undetermined_map(small_scene, small_clouds):
    from fixer4d.render.views import render_views
    from fixer4d.restore.undetermined import undetermined_map

    a = _trainer(small_scene, small_clouds, small_config(ITERATIONS))
    b = _trainer(small_scene, small_clouds, small_config(ITERATIONS))
    a.train(60)
    b.train(60)
    cam = small_scene.cameras[small_scene.test_ids[0]]
    rgb_a, _, alpha_a = render_views(a.model, [cam], 0.5, "auto")
    rgb_b, _, alpha_b = render_views(b.model, [cam], 0.5, "auto")
    assert not undetermined_map(rgb_a[0], rgb_b[0], alpha_a[0], alpha_b[0]).any()


def test_co_fields_train_to_the_end_and_a_killed_run_resumes_to_the_same_fields(small_scene, small_clouds, tmp_path):
    from fixer4d.train.checkpoints import list_checkpoints

    whole = _co(small_scene, small_clouds, tmp_path / "whole")
    assert whole.prune_steps, "the schedule has co-pruning steps"
    whole.train()
    assert whole.a.step_count == whole.b.step_count == ITERATIONS
    assert len(whole.history) == len(whole.prune_steps)
    assert not torch.equal(whole.a.model.means[:10], whole.b.model.means[:10])  # other seeds

    killed = _co(small_scene, small_clouds, tmp_path / "killed")
    killed.a.train(whole.prune_steps[0])  # field A reached the first co-pruning, field B did not save
    assert list_checkpoints(killed.b.run_dir, 1) == []
    resumed = _co(small_scene, small_clouds, tmp_path / "killed")
    assert resumed.resume() is False  # no step both hold: a clean restart
    assert list_checkpoints(resumed.a.run_dir, 1) == []
    resumed.train()

    partial = _co(small_scene, small_clouds, tmp_path / "partial")
    partial.a.train(whole.prune_steps[0])
    partial.b.train(whole.prune_steps[0])  # killed before the co-pruning of that step
    again = _co(small_scene, small_clouds, tmp_path / "partial")
    assert again.resume() is True and again.a.step_count == whole.prune_steps[0]
    again.train()
    for done in (resumed, again):
        for x, y in ((done.a, whole.a), (done.b, whole.b)):
            assert torch.equal(x.model.means, y.model.means)


def test_the_config_round_trips_and_off_keeps_the_stage_keys():
    from fixer4d.errors import InputError
    from fixer4d.pipeline.config import RunConfig, resolve
    from fixer4d.pipeline.keys import stage1_key, stage2_key

    off = resolve("demo")
    assert off.co_fields.enabled is False and off.co_fields.weight == "visibility"
    on = resolve("demo", overrides={"co_fields.enabled": True, "co_fields.weight": "max"})
    assert RunConfig.from_dict(on.to_dict()) == on
    # settings of an option that is off change no key; on, they key stage 1 (and the weight stage 2 only)
    off_tuned = resolve("demo", overrides={"co_fields.prune_distance": 0.05, "co_fields.weight": "max"})
    assert stage1_key(off_tuned, "mvs") == stage1_key(off, "mvs") and stage2_key(off_tuned) == stage2_key(off)
    assert stage1_key(on, "mvs") != stage1_key(off, "mvs")
    assert stage1_key(on, "sparse") == stage1_key(off, "sparse")  # the sparse baseline trains alone
    on_vis = resolve("demo", overrides={"co_fields.enabled": True})
    assert stage1_key(on_vis, "mvs") == stage1_key(on, "mvs") and stage2_key(on_vis) != stage2_key(on)
    with pytest.raises(InputError):
        resolve("demo", overrides={"co_fields.weight": "both"})
