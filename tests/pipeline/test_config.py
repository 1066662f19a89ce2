"""The typed RunConfig: built from defaults + file + overrides, validated in full before anything
is written; every bad input is one clear line with exit code 2 and no folder left behind."""
from __future__ import annotations

import json

import pytest

from fixer4d.cli import main
from fixer4d.errors import InputError
from fixer4d.pipeline import config_tree
from fixer4d.pipeline.config import FORMAT_VERSION, RunConfig, migrate_v1, resolve
from fixer4d.train.config import TrainingConfig


def test_defaults_and_schedule_scaling():
    c = resolve("demo")
    assert c.scene.source == "demo" and c.training.iterations == 1500 and c.training.max_gaussians == 20_000
    # the densification schedule follows the iterations unless given explicitly
    short = resolve("demo", overrides={"training.iterations": 100})
    assert short.training.densify_until == 50
    assert resolve("demo", overrides={"training.iterations": 100, "training.densify_until": 70}).training.densify_until == 70


def test_a_new_iteration_count_rescales_a_written_out_schedule():
    """A run's config.json (or a study's base) writes the schedule derived from its iterations;
    overriding the iterations derives it again, except keys the user set to other values or
    gives beside the new count."""
    from fixer4d.study import variant_config
    from fixer4d.train.config import SCHEDULE_KEYS

    full = resolve("demo").to_dict()
    longer = resolve(config_file=full, overrides={"training.iterations": 3000}, defaults={})
    derived = TrainingConfig.for_iterations(3000)
    assert all(getattr(longer.training, k) == getattr(derived, k) for k in SCHEDULE_KEYS)
    assert longer.training.densify_until == 1500 and longer.training.opacity_reset_every == 750

    full["training"]["densify_until"] = 400  # set by the user: kept
    kept = resolve(config_file=full, overrides={"training.iterations": 3000}, defaults={})
    assert kept.training.densify_until == 400 and kept.training.opacity_reset_every == 750
    given = resolve(config_file=full, overrides={"training.densify_every": 37, "training.iterations": 3000}, defaults={})
    assert given.training.densify_every == 37

    # the study's relative iteration axis: the schedule follows the variant's own count
    half = variant_config("demo", {"training.iterations": 0.5}, base={"training.iterations": 300})
    double = variant_config("demo", {"training.iterations": 2.0}, base={"training.iterations": 300})
    assert (half.training.iterations, half.training.densify_until) == (150, 75)
    assert (double.training.iterations, double.training.densify_until) == (600, 300)


def test_round_trip_is_exact():
    c = resolve("tiny", overrides={"scene.frame_range": [0, 3], "training.background": [0.5, 0.5, 0.5]})
    again = RunConfig.from_dict(json.loads(json.dumps(c.to_dict())))
    assert again == c and again.to_dict() == c.to_dict()


@pytest.mark.parametrize("overrides, message", [
    ({"training.iteratoins": 800}, "did you mean 'iterations'"),
    ({"training.iterations": "many"}, "training.iterations: expected an integer"),
    ({"init.method": "mvz"}, "did you mean 'mvs'"),
    ({"stage2.lambda_gen": -1}, "lambda_gen must be >= 0"),
    ({"scene.frame_range": [5, 2]}, "frame_range"),
    ({"trajectories": 3}, "expected a section"),
    ({"eval.stride": 0}, "stride must be >= 1"),
    ({"training.iterations.x": 3}, "training.iterations: expected an integer"),
    ({"seeed": 1}, "did you mean 'seed'"),
    ({"seed": -1}, "seed must be a whole number >= 0, got -1"),  # numpy's generators raise deep in a run
    ({"training.seed": -3}, "training.seed must be a whole number >= 0"),
    ({"restorer.learned.seed": -1}, "restorer.learned.seed must be"),
])
def test_bad_values_name_the_key(overrides, message):
    with pytest.raises(InputError, match=message):
        resolve("tiny", overrides=overrides)


def test_relative_knobs_multiply():
    c = resolve("tiny", overrides={"training.iterations": 0.5, "init.mvs.planes": 0.5},
                relative={"training.iterations", "init.mvs.planes"})
    assert c.training.iterations == 750 and isinstance(c.init.mvs.planes, int)


def test_set_overrides_parse_json_values():
    assert config_tree.parse_set_overrides(["training.iterations=800", "scene.frame_range=[0, 30]",
                                            "init.method=sparse"]) == {
        "training.iterations": 800, "scene.frame_range": [0, 30], "init.method": "sparse"}
    with pytest.raises(InputError, match="KEY=VALUE"):
        config_tree.parse_set_overrides(["training.iterations"])


def test_format_1_configs_migrate():
    old_run = {"scene": {"source": "tiny", "scale": 1.0, "frame_range": None},
               "pipeline": {"scene": {"source": "tiny", "scale": 1.0, "frame_range": None},
                            "init": {"method": "mvs"}, "baseline_sparse": True,
                            "stage1": {"iterations": 500, "max_gaussians": 30000}, "stage2": {"rounds": 2},
                            "trajectories": {"frames": 6}, "restorer": {}, "init_frame_stride": 4,
                            "eval_stride": 5, "restoration_rows": True, "seed": 0}}
    c = RunConfig.from_dict(migrate_v1(old_run))
    assert c.eval.stride == 5 and c.training.max_gaussians == 30000 and c.stage2.rounds == 2
    old_reconstruct = {"scene": {"source": "tiny", "scale": 1.0, "frame_range": None}, "init": {"method": "sparse"},
                       "stage1": {"iterations": 12, "progress": False}}
    c = RunConfig.from_dict(migrate_v1(old_reconstruct))
    assert c.init.method == "sparse" and c.training.iterations == 12 and not c.baseline_sparse


@pytest.mark.parametrize("argv, message", [
    (["run", "tiny", "--out", "{out}", "--set", "training.iteratoins=800"], "did you mean 'iterations'"),
    (["run", "tiny", "--out", "{out}", "--set", "training.iterations=lots"], "expected an integer"),
    (["run", "tiny", "--out", "{out}", "--frames", "5:2"], "empty range"),
    (["run", "tiny", "--out", "{out}", "--frames", "2"], "expected a:b"),
    (["run", "tiny", "--out", "{out}", "--frames", "0:99"], "frame"),
    (["run", "no/such/scene", "--out", "{out}"], "no such"),
    (["reconstruct", "tiny", "--out", "{out}", "--frames", "3:1"], "--frames"),
    (["run", "tiny", "--out", "{out}", "--config", "{tmp}/missing.json"], "no such file"),
])
def test_cli_bad_input_exits_2_and_writes_nothing(tmp_path, capsys, argv, message):
    out = tmp_path / "run"
    argv = [a.replace("{out}", str(out)).replace("{tmp}", str(tmp_path)) for a in argv]
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err and len(err.strip().splitlines()) == 1
    assert not out.exists()


def test_print_config_shows_the_resolved_tree(capsys, tmp_path):
    assert main(["run", "tiny", "--print-config", "--iterations", "77", "--set", "stage2.rounds=3"]) == 0
    printed = json.loads(capsys.readouterr().out)
    assert printed["format_version"] == FORMAT_VERSION
    assert printed["config"]["training"]["iterations"] == 77 and printed["config"]["stage2"]["rounds"] == 3
    # the printed config is a valid --config file
    (tmp_path / "c.json").write_text(json.dumps(printed))
    assert main(["run", "tiny", "--print-config", "--config", str(tmp_path / "c.json")]) == 0
    assert json.loads(capsys.readouterr().out) == printed


def test_run_seed_flag_seeds_every_stage(capsys):
    """`fixer4d run --seed S` changes what trains (stage 1 and 2 draw from their own seeds);
    `--set seed=S` alone would only reseed torch and leave the rows as they were."""
    assert main(["run", "tiny", "--print-config", "--seed", "3"]) == 0
    cfg = json.loads(capsys.readouterr().out)["config"]
    assert cfg["seed"] == cfg["training"]["seed"] == cfg["stage2"]["seed"] == 3
    assert main(["run", "tiny", "--print-config"]) == 0
    cfg = json.loads(capsys.readouterr().out)["config"]
    assert cfg["seed"] == cfg["training"]["seed"] == cfg["stage2"]["seed"] == 0


def test_a_scene_path_is_stored_absolute(tmp_path, monkeypatch):
    spec = tmp_path / "my_scene.json"
    spec.write_text("{}")
    monkeypatch.chdir(tmp_path)
    assert resolve("my_scene.json").scene.source == str(spec.resolve())
    assert resolve("demo").scene.source == "demo"  # bundled names stay names


def test_the_dataclasses_are_the_one_source_of_defaults():
    """A run's defaults are the stage dataclasses' own, and their schedule is the one their
    iteration count derives (so a default config and a rescheduled one agree)."""
    assert resolve().to_dict() == RunConfig().to_dict()
    assert TrainingConfig() == TrainingConfig.for_iterations(TrainingConfig.iterations)


def _notes(caplog) -> list[str]:
    return [r.getMessage() for r in caplog.records if "is now called" in r.getMessage()]


def test_a_stage1_section_and_set_key_still_load_with_a_note(tmp_path, caplog):
    old = tmp_path / "old.json"
    old.write_text(json.dumps({"stage1": {"iterations": 77, "seed": 4}}))
    with caplog.at_level("WARNING", logger="fixer4d.pipeline"):
        c = resolve("tiny", config_file=old)
    assert (c.training.iterations, c.training.seed) == (77, 4)
    assert c.training.densify_until == TrainingConfig.for_iterations(77).densify_until
    assert _notes(caplog) == [f"--config {old}: config section 'stage1' is now called 'training' (read as 'training')"]
    caplog.clear()
    with caplog.at_level("WARNING", logger="fixer4d.pipeline"):
        c = resolve("tiny", overrides={"stage1.iterations": 90, "stage1.max_gaussians": 5000})
    assert (c.training.iterations, c.training.max_gaussians) == (90, 5000)
    assert len(_notes(caplog)) == 2 and "--set stage1.iterations" in _notes(caplog)[0]
    with pytest.raises(InputError, match="'stage1' and 'training' are the same section"):
        resolve("tiny", config_file={"stage1": {"seed": 1}, "training": {"seed": 2}})


def test_a_run_folder_written_before_the_rename_resumes_under_the_same_keys(tmp_path, caplog):
    from fixer4d.pipeline.keys import stage1_key, stage2_key
    from fixer4d.pipeline.run_folder import RunFolder

    config = resolve("tiny", overrides={"training.iterations": 12})
    run = RunFolder.create(tmp_path / "run", config).path
    stored = json.loads((run / "config.json").read_text())
    stored["format_version"] = 2  # as the run folders made before "training" was called so
    stored["config"] = {("stage1" if k == "training" else k): v for k, v in stored["config"].items()}
    (run / "config.json").write_text(json.dumps(stored))
    with caplog.at_level("WARNING", logger="fixer4d.pipeline"):
        folder = RunFolder.create(run, config)  # the same configuration: resumes, nothing refused
    assert len(_notes(caplog)) == 1 and str(run / "config.json") in _notes(caplog)[0]
    assert folder.config == config
    assert (stage1_key(folder.config, "mvs"), stage2_key(folder.config)) == (stage1_key(config, "mvs"), stage2_key(config))
    rewritten = json.loads((run / "config.json").read_text())
    assert rewritten["format_version"] == FORMAT_VERSION and "training" in rewritten["config"]


def test_an_effects_section_and_set_key_still_load_as_model_terms_with_a_note(tmp_path, caplog):
    old = tmp_path / "old.json"
    old.write_text(json.dumps({"effects": {"mode": "static", "sh_degree": 0}}))
    with caplog.at_level("WARNING", logger="fixer4d.pipeline"):
        c = resolve("tiny", config_file=old)
    assert (c.model_terms.mode, c.model_terms.sh_degree) == ("static", 0)
    assert _notes(caplog) == [f"--config {old}: config section 'effects' is now called 'model_terms' "
                              "(read as 'model_terms')"]
    caplog.clear()
    with caplog.at_level("WARNING", logger="fixer4d.pipeline"):
        c = resolve("tiny", overrides={"effects.mode": "all"})
    assert c.model_terms.mode == "all"
    assert _notes(caplog) == ["--set effects.mode: config section 'effects' is now called 'model_terms'; "
                              "read as model_terms.mode"]
    with pytest.raises(InputError, match="'effects' and 'model_terms' are the same section"):
        resolve("tiny", config_file={"effects": {"mode": "all"}, "model_terms": {"mode": "auto"}})


def test_a_run_folder_with_an_effects_section_resumes_under_the_same_keys(tmp_path, caplog):
    """A run folder made before the model terms were called so: config.json with "effects" (and
    "stage1"), model_effects.json beside the stage-1 model. It resumes under the keys it was made
    with (a key hashes a section's contents, not its name) and its terms file is still read."""
    from fixer4d.pipeline import stages
    from fixer4d.pipeline.keys import stage1_key, stage2_key
    from fixer4d.pipeline.run_folder import RunFolder

    config = resolve("tiny", overrides={"training.iterations": 12, "model_terms.mode": "static"})
    run = RunFolder.create(tmp_path / "run", config).path
    stored = json.loads((run / "config.json").read_text())
    stored["format_version"] = 2
    former = {"training": "stage1", "model_terms": "effects"}
    stored["config"] = {former.get(k, k): v for k, v in stored["config"].items()}
    (run / "config.json").write_text(json.dumps(stored))
    with caplog.at_level("WARNING", logger="fixer4d.pipeline"):
        folder = RunFolder.create(run, config)  # the same configuration: resumes, nothing refused
    assert len(_notes(caplog)) == 2 and folder.config == config
    assert (stage1_key(folder.config, "mvs"), stage2_key(folder.config)) == (stage1_key(config, "mvs"), stage2_key(config))
    rewritten = json.loads((run / "config.json").read_text())
    assert rewritten["format_version"] == FORMAT_VERSION and "model_terms" in rewritten["config"]
    assert "effects" not in rewritten["config"]

    assert stages.terms_path(run) == run / "model_terms.json"  # neither file: the current name
    (run / "model_effects.json").write_text(json.dumps({"mode": "static"}))
    assert stages.terms_path(run) == run / "model_effects.json"  # only the former one: read it
    (run / "model_terms.json").write_text(json.dumps({"mode": "auto"}))
    assert stages.terms_path(run) == run / "model_terms.json"  # both: the current one wins


def test_stage1config_is_a_deprecated_name_of_trainingconfig():
    import fixer4d.train.config as train_config

    with pytest.deprecated_call(match="Stage1Config is now TrainingConfig"):
        assert train_config.Stage1Config is TrainingConfig


def test_a_saved_run_config_without_a_later_setting_reads_as_its_run_had_it(tmp_path):
    """training.fields came after run folders were written: one without it ran one field, whatever
    today's default; a new run gets the default. self_check.fields came later: a fold saved
    without it trained every field of its run."""
    import json

    from fixer4d.pipeline.config import SAVED_BEFORE, RunConfig, resolve
    from fixer4d.pipeline.run_folder import RunFolder, read_run_config
    from fixer4d.pipeline.self_check import fold_fields

    folder = RunFolder.create(tmp_path / "run", resolve("tiny"))
    data = json.loads((folder.path / "config.json").read_text())
    assert data["config"]["training"]["fields"] == RunConfig().training.fields
    del data["config"]["training"]["fields"]
    (folder.path / "config.json").write_text(json.dumps(data))
    assert read_run_config(folder.path).training.fields == SAVED_BEFORE[("training", "fields")] == 1
    del data["config"]["self_check"]["fields"]
    data["config"]["training"]["fields"] = 4
    (folder.path / "config.json").write_text(json.dumps(data))
    assert fold_fields(read_run_config(folder.path)) == 4
