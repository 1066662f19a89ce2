"""Held-out cameras are unreachable from every stage but evaluation (TrainOnlyView), checked on a
whole run by a spy scene; a stage that reads one is caught, either way it tries."""
from __future__ import annotations

import pytest

from fixer4d.pipeline import stages as S
from fixer4d.scene.train_view import HeldOutAccess
from pipeline_tiny import run_spied, tiny_config


def test_a_whole_run_reads_held_out_cameras_only_to_evaluate(tiny_spied_run):
    _, report, spy = tiny_spied_run
    assert spy.violations == []
    assert spy.evaluation_reads > 0  # the spy sees the evaluation's reads: it is wired in


def test_a_stage_reading_a_held_out_frame_is_caught(tmp_path, monkeypatch):
    # a deliberately broken stage 1, first through the stages' own (train-only) scene ...
    real_stage1 = S.stage1

    def leaky_stage1(ctx, method, clouds, model_path, name):
        ctx.train_scene.frame(0, ctx.scene.test_ids[0])
        return real_stage1(ctx, method, clouds, model_path, name)

    monkeypatch.setattr(S, "stage1", leaky_stage1)
    config = tiny_config(**{"baseline_sparse": False, "training.iterations": 5, "stage2.rounds": 0,
                            "eval.restoration_rows": False})
    with pytest.raises(HeldOutAccess, match="held-out cameras are for evaluation only"):
        run_spied(config, tmp_path / "a")

    # ... then around it, through the full scene: the spy names the stage
    def sneaky_stage1(ctx, method, clouds, model_path, name):
        ctx.scene.frame(0, ctx.scene.test_ids[0])
        return real_stage1(ctx, method, clouds, model_path, name)

    monkeypatch.setattr(S, "stage1", sneaky_stage1)
    _, spy = run_spied(config, tmp_path / "b")
    what, cam, where = spy.violations[0]
    assert (what, cam) == ("frame", spy.test_ids[0]) and "run_stages" in where
