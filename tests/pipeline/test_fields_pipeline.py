"""training.fields in the pipeline: the main init's stage 1 as two fields, merged into the model
every later stage continues from; the sparse baseline stays one field."""
from __future__ import annotations

import json
import shutil

import pytest
import torch

from pipeline_tiny import run_spied, tiny_config

TWO = {"training.fields": 2, "self_check.enabled": False}


def test_two_fields_are_trained_apart_and_merged(tmp_path, stage_cache, one_field_run):
    from fixer4d.model.io import load_ply
    from fixer4d.train.fields import FIELD_MODEL, field_dir, merge_fields

    run_dir = tmp_path / "two"
    report, spy = run_spied(tiny_config(**TWO), run_dir, stage_cache)  # stage 1 may come from the cache
    assert not spy.violations
    fields = [load_ply(field_dir(run_dir, k) / FIELD_MODEL) for k in range(2)]
    one_field = load_ply(one_field_run[0] / "model_stage1.ply")
    # field 0 is the one-field run's stage 1 (the same seed); field 1 another seed's
    torch.testing.assert_close(fields[0].means, one_field.means, rtol=0, atol=0)
    assert fields[1].num_gaussians != fields[0].num_gaussians or not torch.equal(fields[1].means, fields[0].means)
    merged = load_ply(run_dir / "model_stage1.ply")
    want = merge_fields(fields)
    assert merged.num_gaussians == fields[0].num_gaussians + fields[1].num_gaussians
    torch.testing.assert_close(merged.opacity_logits, want.opacity_logits)
    terms = json.loads((run_dir / "model_terms.json").read_text())
    assert terms["fields"] == 2 and terms["gaussians"] == merged.num_gaussians
    for k in range(2):  # a finished stage drops the fields' checkpoints
        assert not list(field_dir(run_dir, k).rglob("*.pt"))
    baseline = load_ply(run_dir / "baseline_sparse" / "model_stage1.ply")
    assert baseline.num_gaussians <= tiny_config().training.max_gaussians
    rows = {r["method"]: r for r in report["rows"]}
    assert rows["Full"]["status"] == "ok" and rows["STGS w/ MVS"]["status"] == "ok"


def test_the_self_checks_fold_trains_fields_as_the_run_does(tmp_path, stage_cache):
    """The fold checks stage 2 on the kind of model the run refines: two fields merged, whose
    opacities are at most 1/2 (each field's sigmoid halved)."""
    from fixer4d.model.io import load_ply
    from fixer4d.pipeline.self_check_run import FOLD_MODEL

    run_dir = tmp_path / "checked"
    report, spy = run_spied(tiny_config(**{"training.fields": 2}), run_dir, stage_cache)
    assert not spy.violations
    folds = sorted(run_dir.glob(f"self_check/**/{FOLD_MODEL}"))
    assert folds
    for path in folds + [run_dir / "model_stage1.ply"]:
        assert float(torch.sigmoid(load_ply(path).opacity_logits.detach()).max()) <= 0.5 + 1e-6, path
    assert not list((run_dir / "self_check").rglob("*.pt"))
    assert report["self_check"]["decision"] in ("skip", "refine")


def test_a_stage1_killed_between_fields_resumes_from_the_finished_field(tmp_path, stage_cache):
    from fixer4d.model.io import load_ply
    from fixer4d.pipeline.run import open_context, run_stages
    from fixer4d.train.fields import FIELD_MODEL, FIELD_RECORD, field_dir

    config = tiny_config(**TWO, **{"stage2.rounds": 0, "baseline_sparse": False})
    done = tmp_path / "done"
    run_stages(open_context(config, done, progress=False))
    killed = tmp_path / "killed"
    shutil.copytree(done, killed)
    # as if killed while field 1 trained: field 0 written, nothing after it
    (killed / "model_stage1.ply").unlink()
    shutil.rmtree(field_dir(killed, 1))
    records = json.loads((killed / "stages.json").read_text())
    records["stage1"]["done"] = False
    for name in [n for n in records if n not in ("init_mvs", "stage1")]:
        del records[name]
    (killed / "stages.json").write_text(json.dumps(records))
    field0 = field_dir(killed, 0) / FIELD_MODEL
    written = field0.stat().st_mtime_ns
    run_stages(open_context(config, killed, progress=False))
    assert field0.stat().st_mtime_ns == written  # read back, not trained again
    field0_seconds = json.loads((field_dir(killed, 0) / FIELD_RECORD).read_text())["train_seconds"]
    assert json.loads((killed / "stages.json").read_text())["stage1"]["seconds"] > field0_seconds > 0
    torch.testing.assert_close(load_ply(killed / "model_stage1.ply").means, load_ply(done / "model_stage1.ply").means,
                               rtol=0, atol=0)


def test_more_fields_on_a_finished_run_train_only_the_new_ones(tmp_path):
    """A field trains the same whatever the field count: a run folder given a third field (its
    config.json rewritten, as a study that copies run folders does) reads fields 0 and 1 back,
    their files untouched, and merges three; a setting that changes every field's training drops
    them all."""
    from fixer4d.model.io import load_ply
    from fixer4d.pipeline.run import open_context, run_stages
    from fixer4d.pipeline.run_folder import RunFolder
    from fixer4d.train.fields import FIELD_KEY, FIELD_MODEL, field_dir, merge_fields

    base = {**TWO, "stage2.rounds": 0, "baseline_sparse": False, "eval.restoration_rows": False,
            "eval.matched_row": False}
    run = tmp_path / "run"
    run_stages(open_context(tiny_config(**base), run, progress=False))
    written = {k: (field_dir(run, k) / FIELD_MODEL).stat().st_mtime_ns for k in range(2)}

    def rerun(config):
        RunFolder.open(run).update_config(config)
        run_stages(open_context(config, run, progress=False))

    rerun(tiny_config(**{**base, "training.fields": 3}))
    assert {k: (field_dir(run, k) / FIELD_MODEL).stat().st_mtime_ns for k in range(2)} == written
    fields = [load_ply(field_dir(run, k) / FIELD_MODEL) for k in range(3)]
    merged = load_ply(run / "model_stage1.ply")
    torch.testing.assert_close(merged.opacity_logits, merge_fields(fields).opacity_logits, rtol=0, atol=0)
    assert json.loads((run / "model_terms.json").read_text())["fields"] == 3
    keys = {(field_dir(run, k) / FIELD_KEY).read_text() for k in range(3)}
    assert len(keys) == 3  # one key per field number
    # another learning rate: no field is read back
    rerun(tiny_config(**{**base, "training.fields": 3, "training.lr_scales": 4e-3}))
    assert all((field_dir(run, k) / FIELD_MODEL).stat().st_mtime_ns != written[k] for k in range(2))
    assert {(field_dir(run, k) / FIELD_KEY).read_text() for k in range(3)}.isdisjoint(keys)


def test_the_sparse_baseline_is_keyed_without_the_field_count():
    from fixer4d.pipeline.keys import stage1_key

    one, three = tiny_config(**{"training.fields": 1}), tiny_config(**{"training.fields": 3})
    assert stage1_key(one, "sparse") == stage1_key(three, "sparse")
    assert stage1_key(one, "mvs") != stage1_key(three, "mvs")


def test_a_field_without_its_key_is_trained_again_under_new_settings(tmp_path):
    from fixer4d.train.fields import FIELD_KEY, keep_matching_fields

    root = tmp_path / "fields"
    for k, key in enumerate(["a", "b", None]):
        (root / f"field{k}").mkdir(parents=True)
        if key is not None:
            (root / f"field{k}" / FIELD_KEY).write_text(key)
    assert keep_matching_fields(tmp_path, lambda k: "ab"[k] if k < 2 else "c") == [0, 1]
    assert sorted(p.name for p in root.iterdir()) == ["field0", "field1"]
    assert keep_matching_fields(tmp_path, lambda k: "x") == [] and not list(root.iterdir())


def test_a_later_segment_merges_its_fields_around_the_shared_static_rows(tmp_path):
    """share_static with two fields: each field of the second segment trains beside the first
    segment's static rows; the merged model holds them once, frozen, bit for bit."""
    from fixer4d.model.io import load_ply
    from fixer4d.pipeline.run import run_pipeline

    base = {"segments.frames": 3, "segments.overlap": 2, "baseline_sparse": False, "eval.restoration_rows": False,
            "eval.matched_row": False, "init_frame_stride": 1, "eval.stride": 1, "restorer.kind": "warp",
            "training.iterations": 30, "stage2.rounds": 0, "segments.share_static": True,
            "self_check.enabled": False, **TWO}
    run_pipeline(tiny_config(**base), tmp_path / "run", progress=False)
    seg = tmp_path / "run" / "segments"
    rows = load_ply(seg / "shared_static" / "stage1.ply")
    later = load_ply(seg / "seg01_00001-00004" / "model_stage1.ply")
    assert later.num_frozen == rows.num_gaussians > 0
    assert torch.equal(later.means[later.frozen], rows.means)
    assert torch.equal(later.opacity_logits[later.frozen], rows.opacity_logits)
    assert float(torch.sigmoid(later.opacity_logits[~later.frozen].detach()).max()) <= 0.5 + 1e-6


def test_stage2_fields_keys_a_run_only_when_apart():
    from fixer4d.pipeline.keys import matched_key, stage2_key
    from fixer4d.train.config import Stage2Config

    from fixer4d.errors import InputError

    assert "fields" not in Stage2Config().keyed()
    with pytest.raises(InputError, match="merged, apart"):
        Stage2Config(fields="both")
    merged, apart = tiny_config(**TWO), tiny_config(**TWO, **{"stage2.fields": "apart"})
    assert stage2_key(apart) != stage2_key(merged) and matched_key(apart) != matched_key(merged)
    # one field has nothing to refine apart: the matched control is the same training
    one = tiny_config(**{"training.fields": 1})
    assert matched_key(tiny_config(**{"training.fields": 1, "stage2.fields": "apart"})) == matched_key(one)


def test_stage2_apart_refines_each_field_and_merges_the_refined_fields(tmp_path, stage_cache):
    """stage2.fields=apart: stage 2 and the matched control continue each field on its own (its
    own budget, seeds and camera response) and the final model is the merge of the refined fields."""
    from fixer4d.model.io import load_ply
    from fixer4d.pipeline.stages import MATCHED_DIR, STAGE2_DIR
    from fixer4d.restore.cache import RestoreCache
    from fixer4d.train.fields import FIELD_MODEL, field_dir, merge_fields

    run_dir = tmp_path / "apart"
    config = tiny_config(**TWO, **{"stage2.fields": "apart"})
    report, spy = run_spied(config, run_dir, stage_cache)
    assert not spy.violations
    for step, merged_path in ((STAGE2_DIR, run_dir / "model_final.ply"), (MATCHED_DIR, run_dir / "matched" / "model.ply")):
        refined = [load_ply(field_dir(run_dir, k, step) / FIELD_MODEL) for k in range(2)]
        stage1 = [load_ply(field_dir(run_dir, k) / FIELD_MODEL) for k in range(2)]
        for r, s in zip(refined, stage1):  # each field was trained on, within one field's budget
            assert r.num_gaussians <= config.training.max_gaussians
            assert r.num_gaussians != s.num_gaussians or not torch.equal(r.means, s.means)
        merged = load_ply(merged_path)
        torch.testing.assert_close(merged.opacity_logits, merge_fields(refined).opacity_logits)
        torch.testing.assert_close(merged.means, merge_fields(refined).means)
        assert not list(field_dir(run_dir, 0, step).glob("*.pt"))  # a finished stage drops its checkpoints
    # field 0's pseudo-targets are the run's cache (the viewer's), field 1's its own
    assert RestoreCache(run_dir / "cache").entries() and RestoreCache(field_dir(run_dir, 1, STAGE2_DIR) / "cache").entries()
    rows = {r["method"]: r for r in report["rows"]}
    assert rows["Full"]["status"] == "ok" and rows["STGS w/ MVS (matched iterations)"]["status"] == "ok"


def test_the_fold_merges_at_most_self_check_fields_fields():
    """A four-field run's fold trains two fields (self_check.fields), a one-field run's one; a
    larger self_check.fields, or 0, gives the fold the run's count, never more; the key holds the
    count the fold trains."""
    from fixer4d.errors import InputError
    from fixer4d.pipeline.keys import self_check_key
    from fixer4d.pipeline.self_check import fold_fields

    four = tiny_config(**{"training.fields": 4})
    assert four.self_check.fields == 2 and fold_fields(four) == 2
    assert fold_fields(tiny_config(**{"training.fields": 1})) == 1
    wide = tiny_config(**{"training.fields": 4, "self_check.fields": 8})
    assert fold_fields(wide) == 4 == fold_fields(tiny_config(**{"training.fields": 4, "self_check.fields": 0}))
    assert self_check_key(wide) != self_check_key(four)
    two = tiny_config(**{"training.fields": 2})
    assert self_check_key(tiny_config(**{"training.fields": 2, "self_check.fields": 3})) == self_check_key(two)
    with pytest.raises(InputError, match="fields >= 0"):
        tiny_config(**{"self_check.fields": -1})


def test_with_fields_refined_apart_the_fold_checks_one_field(tmp_path, stage_cache, monkeypatch):
    """stage2.fields=apart refines every field as one field's model, so the fold trains one field."""
    import fixer4d.train.fields as fields_module
    from fixer4d.pipeline.self_check import fold_fields

    apart = tiny_config(**{"training.fields": 2, "stage2.fields": "apart"})
    assert fold_fields(apart) == 1 and fold_fields(tiny_config(**{"training.fields": 2})) == 2
    labels = []
    train_fields = fields_module.train_fields

    def spy(*args, **kwargs):
        labels.append(kwargs.get("label"))
        return train_fields(*args, **kwargs)

    monkeypatch.setattr(fields_module, "train_fields", spy)
    report, spy_access = run_spied(apart, tmp_path / "apart_checked", stage_cache)
    assert not spy_access.violations
    assert "self-check fold" not in labels and report["self_check"]["decision"] in ("skip", "refine")
    assert (tmp_path / "apart_checked" / "self_check" / "parts.json").is_file()
