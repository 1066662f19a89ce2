"""`fixer4d reconstruct`, `refine` and `eval` go through the same stages and run folders as `run`."""
from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from fixer4d.cli import main
from fixer4d.errors import InputError
from fixer4d.pipeline import report as R
from fixer4d.cli.eval import find_model, method_name_for
from pipeline_tiny import TINY

TINY_ARGS = ["--iterations", "40", "--eval-stride", "2", "--quiet"] + [
    a for k, v in TINY.items() if not k.startswith(("training.iterations", "eval.stride", "stage2."))
    for a in ("--set", f"{k}={v}")]


def test_reconstruct_never_reuses_another_methods_run(tmp_path, capsys):
    run = tmp_path / "r"
    assert main(["reconstruct", "tiny", "--init", "mvs", "--out", str(run)] + TINY_ARGS) == 0
    report = json.loads((run / "report.json").read_text())
    assert [r["method"] for r in report["rows"]] == [R.ROW_MVS]
    capsys.readouterr()
    assert main(["reconstruct", "tiny", "--init", "sparse", "--out", str(run)] + TINY_ARGS) == 2
    assert "init.method: \"mvs\" -> \"sparse\"" in capsys.readouterr().err
    assert not (run / "init_sparse").exists()


def test_refine_continues_a_run_with_its_own_config(tiny_run, tmp_path, capsys):
    src, _ = tiny_run
    run = tmp_path / "copy"
    shutil.copytree(src, run)
    before = json.loads((run / "stages.json").read_text())
    # the run's own config, not refine's defaults: same cap, same trajectories, nothing recomputed
    assert main(["refine", str(run), "--quiet"]) == 0
    assert json.loads((run / "stages.json").read_text()) == before
    # the self-check off: stage 2 runs whatever the fold would say, and fills a cache
    assert main(["refine", str(run), "--set", "self_check.enabled=false", "--quiet"]) == 0
    refined = json.loads((run / "stages.json").read_text())
    assert (run / "cache" / "round_0").is_dir()
    # a new stage-2 setting recomputes stage 2; the old pseudo-targets are moved aside, never reused
    assert main(["refine", str(run), "--refresh-every", "10", "--quiet"]) == 0
    after = json.loads((run / "stages.json").read_text())
    assert after["stage1"] == before["stage1"] and after["stage2"]["key"] != refined["stage2"]["key"]
    assert (run / "stale" / "cache-0" / "round_0").is_dir() and (run / "cache" / "round_0").is_dir()
    config = json.loads((run / "config.json").read_text())["config"]
    assert config["stage2"]["refresh_every"] == 10 and config["training"]["iterations"] == 40
    capsys.readouterr()
    assert main(["refine", str(run), "--set", "training.iterations=10"]) == 2
    assert "would change the stage-1 model" in capsys.readouterr().err


def test_refine_rounds_and_iterations_do_not_leave_stale_results(tiny_run, tmp_path, capsys):
    """A count set by an earlier refine does not outlive new rounds (it made an untrained "Full"),
    and R = 0 moves the earlier stage-2 model aside instead of leaving it as the run's final one."""
    src, _ = tiny_run
    run = tmp_path / "copy"
    shutil.copytree(src, run)
    assert main(["refine", str(run), "--iterations", "0", "--quiet"]) == 2
    assert "must be >= 1" in capsys.readouterr().err
    assert main(["refine", str(run), "--iterations", "3", "--quiet"]) == 0
    assert main(["refine", str(run), "--rounds", "1", "--refresh-every", "4", "--quiet"]) == 0
    assert json.loads((run / "config.json").read_text())["config"]["stage2"]["iterations"] is None
    final = (run / "model_final.ply").read_bytes()
    assert main(["refine", str(run), "--rounds", "0", "--quiet"]) == 0
    assert not (run / "model_final.ply").exists() and (run / "stale" / "model_final.ply-0").read_bytes() == final
    assert "stage2" not in json.loads((run / "stages.json").read_text())
    report = json.loads((run / "report.json").read_text())
    assert R.ROW_FULL not in [r["method"] for r in report["rows"]]
    assert "model_stage1.ply (rounds = 0" in capsys.readouterr().out
    assert find_model(run).name == "model_stage1.ply"  # `fixer4d eval` now scores the stage-1 model


def test_eval_verb_on_a_run(tiny_run, tmp_path, capsys):
    src, report = tiny_run
    run = tmp_path / "copy"
    shutil.copytree(src, run)
    assert main(["eval", str(run), "--stride", "2", "--quiet", "--examples", "0"]) == 0
    res = json.loads((run / "metrics.json").read_text())
    assert res["method"] == R.ROW_FULL and res["model"].endswith("model_final.ply")
    full = next(r for r in report["rows"] if r["method"] == R.ROW_FULL)
    assert res["mean"]["psnr"] == pytest.approx(full["psnr"], abs=1e-6)
    assert res["seconds"]["train"] > 0 and np.isfinite(res["mean"]["psnr"])
    assert "| Full |" in capsys.readouterr().out
    # the default stride is the run's (the report's protocol); another one never replaces its files
    assert main(["eval", str(run), "--quiet", "--examples", "0"]) == 0
    assert json.loads((run / "metrics.json").read_text())["mean"]["psnr"] == pytest.approx(full["psnr"], abs=1e-6)
    before = {p: (run / p).read_bytes() for p in ("metrics.json", "eval/full/metrics.json")}
    assert main(["eval", str(run), "--stride", "1", "--quiet", "--examples", "0"]) == 0
    assert (run / "eval" / "full-stride1" / "metrics.json").is_file()
    assert {p: (run / p).read_bytes() for p in before} == before
    assert "not the run's 2" in capsys.readouterr().out


def test_eval_helpers_and_errors(tmp_path, capsys):
    assert main(["eval", str(tmp_path)]) == 2
    assert "not a fixer4d run folder" in capsys.readouterr().err
    with pytest.raises(InputError, match="model_final.ply or model_stage1.ply"):
        find_model(tmp_path)
    (tmp_path / "model_final.ply").write_bytes(b"")
    (tmp_path / "model_stage1.ply").write_bytes(b"")
    assert find_model(tmp_path).name == "model_final.ply"
    assert method_name_for(tmp_path / "model_final.ply", "mvs") == R.ROW_FULL
    assert method_name_for(tmp_path / "model_stage1.ply", "sparse") == R.ROW_COLMAP
    assert method_name_for(tmp_path / "model_edit_1.ply", "mvs") == "model_edit_1"


def test_a_segmented_run_folder_points_to_its_segments(tmp_path, capsys):
    """export / eval / refine on a segmented run's top folder said "run reconstruct first" although
    the run was complete: its models live in one run folder per segment."""
    from fixer4d.cli.export import missing_model_message

    run = tmp_path / "whole"
    for name in ("seg00_00000-00052", "seg01_00050-00102"):
        (run / "segments" / name).mkdir(parents=True)
    text = missing_model_message(run)
    assert "a segmented run" in text and str(run / "segments" / "seg00_00000-00052") in text
    assert main(["export", str(run), "--out", str(tmp_path / "x.ply")]) == 2
    assert "a segmented run" in capsys.readouterr().err
    assert "reconstruct" in missing_model_message(tmp_path / "empty")
