"""The whole pipeline on the tiny synthetic scene: report contract, resume, run folders, failures."""
from __future__ import annotations

import json

import pytest

from fixer4d.errors import InputError
from fixer4d.pipeline import report as R
from fixer4d.pipeline.config import FORMAT_VERSION
from fixer4d.pipeline.run import run_pipeline
from fixer4d.pipeline.run_folder import RunFolder
from pipeline_tiny import TINY, tiny_config


def test_report_contract(tiny_run):
    run_dir, report = tiny_run
    on_disk = json.loads((run_dir / "report.json").read_text())
    assert [r["method"] for r in on_disk["rows"]] == list(R.ROW_NAMES)
    rows = {r["method"]: r for r in on_disk["rows"]}
    decision = on_disk["self_check"]["decision"]
    # rows whose images are another row's: the stage-1 render itself (no time of its own), and where
    # the check kept stage 1 the final rows (what the final model cost, the check included)
    copied = {R.ROW_IDENTITY: R.ROW_MVS}
    if decision == "skip":
        copied.update({R.ROW_FULL: R.ROW_MVS, R.ROW_RESTORED_REFINED: R.ROW_RESTORED_INIT})
        assert not (run_dir / "eval" / "full").exists()  # not rendered again
    metric_keys = {"psnr", "dssim1", "dssim2", "lpips", "psnr_dynamic", "psnr_static", "psnr_unobserved",
                   "psnr_aligned", "unobserved_fraction"}
    for r in on_disk["rows"]:
        assert r["status"] == "ok"
        keys = {"method", "status", "seconds"} | metric_keys
        if r["method"] in copied:
            source = rows[copied[r["method"]]]
            assert set(r) == keys | {"same_as"} and r["same_as"] == source["method"]
            assert all(r[k] == source[k] for k in metric_keys)
            if r["method"] == R.ROW_IDENTITY:
                assert r["seconds"] is None
                continue
        else:
            assert set(r) == keys
        assert r["psnr"] > 5.0 and 0.0 <= r["dssim1"] <= 1.0 and r["seconds"] > 0
        assert r["psnr_aligned"] >= r["psnr"] - 1e-6  # an affine colour fit never raises the squared error
    assert on_disk["self_check"]["decision"] in ("skip", "continue", "refine")
    assert "Stage-2 self-check" in (run_dir / "report.md").read_text()
    for name in ("report.md", "model_stage1.ply", "model_final.ply", "metrics.json", "config.json",
                 "baseline_sparse/model_stage1.ply", "matched/model.ply", "init_mvs/init_report.json",
                 "init_sparse/init_report.json"):
        assert (run_dir / name).exists(), name
    if decision == "refine":
        # the cache holds the 6 pairs + 2 arcs at the one restored timestamp, in round 0
        keys = sorted(p.name for p in (run_dir / "cache" / "round_0").iterdir() if not p.name.startswith("."))
        assert len(keys) == 8 and keys[0].startswith("t0000_")
    else:  # the final model is the one the check trusted: the stage-1 model or the matched control
        same_as = R.ROW_MVS if decision == "skip" else R.ROW_MATCHED
        assert rows[R.ROW_FULL]["psnr"] == rows[same_as]["psnr"]
    assert rows[R.ROW_FULL]["seconds"] > rows[R.ROW_MVS]["seconds"]
    stored = json.loads((run_dir / "config.json").read_text())
    assert stored["format_version"] == FORMAT_VERSION and stored["config"] == tiny_config().to_dict()


def test_resume_reuses_finished_stages(tiny_run, stage_cache):
    run_dir, report = tiny_run
    stages = json.loads((run_dir / "stages.json").read_text())
    again = run_pipeline(tiny_config(), run_dir, progress=False, stage_cache=stage_cache)
    assert json.loads((run_dir / "stages.json").read_text()) == stages  # nothing was recomputed
    assert again["rows"] == report["rows"]


def test_other_config_in_same_folder_is_refused_naming_the_change(tiny_run):
    run_dir, _ = tiny_run
    with pytest.raises(InputError, match=r"different configuration \(training.iterations: 40 -> 41"):
        run_pipeline(tiny_config(**{"training.iterations": 41}), run_dir, progress=False)
    # a new count moves the schedule it implies too: the key the user changed is named first
    with pytest.raises(InputError, match=r"different configuration \(.*training.iterations: 40 -> 3000.*and \d+ more\)"):
        run_pipeline(tiny_config(**{"training.iterations": 3000, "training.seed": 5, "stage2.seed": 5,
                                    "trajectories.seed": 5}), run_dir, progress=False)


def test_foreign_and_newer_folders_are_refused(tmp_path):
    (tmp_path / "photos").mkdir()
    (tmp_path / "photos" / "a.jpg").write_bytes(b"x")
    with pytest.raises(InputError, match="not a fixer4d run folder"):
        run_pipeline(tiny_config(), tmp_path / "photos", progress=False)
    future = tmp_path / "future"
    future.mkdir()
    (future / "config.json").write_text(json.dumps({"format_version": FORMAT_VERSION + 1, "config": {}}))
    with pytest.raises(InputError, match="newer than this fixer4d"):
        RunFolder.open(future)
    (future / "config.json").write_text("{not json")
    with pytest.raises(InputError, match="not valid JSON"):
        RunFolder.open(future)


def test_read_run_config_never_writes(tmp_path):
    from fixer4d.pipeline.run_folder import read_run_config

    run = tmp_path / "old"
    run.mkdir()
    old = {"scene": {"source": "tiny", "scale": 1.0, "frame_range": None}, "stage1": {"iterations": 12}}
    (run / "config.json").write_text(json.dumps(old))
    assert read_run_config(run).training.iterations == 12
    assert json.loads((run / "config.json").read_text()) == old and not (run / "config.v1.json").exists()
    with pytest.raises(InputError, match="no such run folder"):
        read_run_config(tmp_path / "missing")


def test_format_1_folder_is_migrated_in_place(tmp_path):
    run = tmp_path / "old"
    run.mkdir()
    old = {"scene": {"source": "tiny", "scale": 1.0, "frame_range": None}, "init": {"method": "mvs"},
           "stage1": {"iterations": 12, "progress": False}}
    (run / "config.json").write_text(json.dumps(old))
    (run / "stages.json").write_text(json.dumps({"init_mvs": 1.5, "stage1": 3.0}))
    folder = RunFolder.open(run)
    assert folder.config.training.iterations == 12
    assert json.loads((run / "config.v1.json").read_text()) == old
    assert json.loads((run / "config.json").read_text())["format_version"] == FORMAT_VERSION
    assert folder.records.seconds("init_mvs", "stage1") == 4.5
    assert folder.records.done("stage1", "any-key")  # format-1 records are adopted once ...
    assert not folder.records.done("stage1", "another-key")  # ... then keyed like the rest


def test_failing_baseline_is_reported_while_the_main_method_runs(tmp_path, stage_cache, monkeypatch):
    from fixer4d.pipeline import stages as S

    real = S.init_stage

    def no_sparse_points(ctx, method):
        if method == "sparse":
            raise S.StageFailed("the sparse (COLMAP) init triangulated no points on any of its 2 init frames")
        return real(ctx, method)

    monkeypatch.setattr(S, "init_stage", no_sparse_points)
    report = run_pipeline(tiny_config(**{"stage2.rounds": 0, "eval.restoration_rows": False}), tmp_path / "r",
                          progress=False, stage_cache=stage_cache)
    rows = {r["method"]: r for r in report["rows"]}
    assert rows[R.ROW_COLMAP]["status"] == "failed" and "no points" in rows[R.ROW_COLMAP]["error"]
    assert rows[R.ROW_MVS]["status"] == "ok" and rows[R.ROW_MVS]["psnr"] > 5
    assert "failed: the sparse (COLMAP) init triangulated no points" in (tmp_path / "r" / "report.md").read_text()


def test_study_variants_share_stages(tmp_path, stage_cache):
    from fixer4d.study import run_pipeline_variant

    cache = tmp_path / "study_cache"
    a = run_pipeline_variant("tiny", {"stage2.rounds": 0}, tmp_path / "a", progress=False, base=TINY, stage_cache=cache)
    b = run_pipeline_variant("tiny", {"stage2.rounds": 0, "eval.stride": 4}, tmp_path / "b", progress=False, base=TINY,
                             stage_cache=cache)
    assert a["method"] == R.ROW_MVS and set(a) >= {"psnr", "dssim1", "dssim2", "lpips", "seconds"}
    assert a["seconds"]["total"] == pytest.approx(sum(v for k, v in a["seconds"].items() if k != "total"))
    # b copied a's init and stage-1 model and reports the seconds they originally cost
    assert b["seconds"]["init"] == a["seconds"]["init"] and b["seconds"]["stage1"] == a["seconds"]["stage1"]
    assert (tmp_path / "b" / "model_stage1.ply").read_bytes() == (tmp_path / "a" / "model_stage1.ply").read_bytes()
    # training.iterations is a relative knob in a variant: 0.75 x the base's 40 iterations
    c = run_pipeline_variant("tiny", {"stage2.rounds": 0, "training.iterations": 0.75}, tmp_path / "c",
                             progress=False, base=TINY, stage_cache=cache)
    assert json.loads((tmp_path / "c" / "config.json").read_text())["config"]["training"]["iterations"] == 30
    assert c["seconds"]["init"] == a["seconds"]["init"]  # same init, new stage 1
    assert (tmp_path / "c" / "model_stage1.ply").read_bytes() != (tmp_path / "a" / "model_stage1.ply").read_bytes()


def test_a_rerun_removes_what_a_killed_write_left(tmp_path):
    run = tmp_path / "r"
    RunFolder.create(run, tiny_config())
    (run / "eval").mkdir()
    leftovers = [run / ".model_stage1.ply.k3j_9xa2.ply", run / "eval" / ".metrics.json.ab12cd34.json",
                 run / ".round_0.tmp.zz99yy88"]
    for p in leftovers[:2]:
        p.write_text("half")
    leftovers[2].mkdir()
    (run / ".keep_me").write_text("not ours")
    RunFolder.create(run, tiny_config())
    assert not any(p.exists() for p in leftovers) and (run / ".keep_me").exists()


def test_matched_control_trains_a_copy_of_the_stage1_model(tiny_run, tmp_path):
    """Stage 2 must start from the stage-1 model, not from the matched control's (a Trainer
    updates its model in place): a fresh run and a resumed one would differ otherwise."""
    import shutil

    import torch

    from fixer4d.model.io import load_ply
    from fixer4d.pipeline import stages as S

    run = tmp_path / "copy"
    shutil.copytree(tiny_run[0], run)
    shutil.rmtree(run / "matched")
    folder = RunFolder.open(run)
    ctx = S.StageContext(run=folder, scene=folder.scene, progress=False)
    model = load_ply(run / "model_stage1.ply")
    before = {k: v.detach().clone() for k, v in model.state_dict().items()}
    matched = S.matched_stage1(ctx, model)
    assert matched is not model
    after = model.state_dict()
    assert before.keys() == after.keys() and all(torch.equal(before[k], after[k]) for k in before)


def test_restoration_rows_are_keyed_by_the_gate_settings():
    # a restoration row computed under another gate (its fallback, its thresholds) is not reused
    from fixer4d.pipeline.run import gate_settings
    from fixer4d.pipeline.run_folder import stage_key
    from fixer4d.restore.visibility import VisibilityConfig

    keys = {stage_key("s1", gate_settings(g, fill)) for g, fill in
            ((None, True), (VisibilityConfig(), True), (VisibilityConfig(), False),
             (VisibilityConfig(angle_full_deg=20.0), True))}
    assert len(keys) == 4 and gate_settings(None, False) is None


def test_a_finished_run_leaves_no_stage_checkpoint_and_records_its_device(tiny_run):
    from fixer4d.train.device import device_kind

    run_dir, report = tiny_run
    assert sorted(str(p.relative_to(run_dir)) for p in run_dir.rglob("*.pt")) == []
    training = tiny_config().training
    assert report["training_device"] == device_kind(training.device, training.backend)


def test_keep_checkpoints_keeps_each_finished_stages_newest(tmp_path):
    config = tiny_config(**{"baseline_sparse": False, "eval.matched_row": False, "eval.restoration_rows": False,
                            "self_check.enabled": False})
    run_pipeline(config, tmp_path / "run", progress=False, keep_checkpoints=True)
    kept = sorted(p.name for p in (tmp_path / "run" / "checkpoints").iterdir())
    assert kept and all(n.startswith("stage2_") for n in kept)  # stage 1 trains its fields apart
    assert len(kept) <= config.training.keep_checkpoints
    for k in range(config.training.fields):
        stage1 = sorted(p.name for p in (tmp_path / "run" / "fields" / f"field{k}" / "checkpoints").iterdir())
        assert 1 <= len(stage1) <= config.training.keep_checkpoints and all(n.startswith("stage1_") for n in stage1)
        assert stage1[-1] == f"stage1_{config.training.iterations:07d}.pt"
