"""Stage 1's fields and the self-check fold's trained side by side in worker processes
(``training.field_workers``) give the run that trains them one after the other, byte for byte."""
from __future__ import annotations

import json

from pipeline_tiny import tiny_config


def test_fields_in_workers_give_the_same_run_as_fields_in_process(tmp_path, tiny_spied_run):
    from fixer4d.pipeline.run import open_context, run_stages
    from fixer4d.pipeline.self_check_run import FOLD_MODEL
    from fixer4d.train.fields import FIELD_MODEL, field_dir

    in_process, report_in_process, _ = tiny_spied_run  # fields one after the other (field_workers=1)
    config = tiny_config(**{"training.field_workers": 2})
    assert config.training.fields == 2 and config.self_check.enabled and config.stage2.rounds > 0
    ctx = open_context(config, tmp_path / "workers", progress=False)  # no stage cache: every field trains
    assert ctx.scene_from_config
    report = run_stages(ctx)
    workers = ctx.path
    for k in range(2):
        assert (field_dir(workers, k) / FIELD_MODEL).read_bytes() == (field_dir(in_process, k) / FIELD_MODEL).read_bytes()
    for name in ("model_stage1.ply", f"self_check/{FOLD_MODEL}", "model_final.ply"):
        assert (workers / name).read_bytes() == (in_process / name).read_bytes(), name
    decision = json.loads((workers / "self_check" / "decision.json").read_text())
    assert decision["psnr"] == report_in_process["self_check"]["psnr"]

    def rows(r):
        return {row["method"]: {k: row.get(k) for k in ("psnr", "ssim", "lpips", "status")} for row in r["rows"]}

    assert rows(report) == rows(report_in_process)
    assert "field_workers" not in json.dumps(report["rows"])


def test_a_resumed_run_may_change_how_it_runs_not_what_it_computes(tmp_path):
    import pytest

    from fixer4d.errors import InputError
    from fixer4d.pipeline.run_folder import RunFolder

    RunFolder.create(tmp_path / "run", tiny_config(**{"training.field_workers": 2}))
    again = RunFolder.create(tmp_path / "run", tiny_config(**{"training.field_workers": 1,
                                                              "training.checkpoint_every": 10}))
    assert again.config.training.field_workers == 1 and again.config.training.checkpoint_every == 10
    with pytest.raises(InputError, match="training.fields"):
        RunFolder.create(tmp_path / "run", tiny_config(**{"training.field_workers": 1, "training.checkpoint_every": 10,
                                                          "training.fields": 3}))
