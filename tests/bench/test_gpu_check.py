"""benchmarks/gpu_check.sh and the scripts it calls, on a machine without a GPU: the dry run lists
every stage within the budget of one lent session and names files that exist; the step
benchmark's CPU fallback times both loops; the report gathers stages, runs and the step."""
from __future__ import annotations

import json
import re
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
SCRIPT = ROOT / "benchmarks" / "gpu_check.sh"
STAGES = ["install", "build", "tests", "demo", "panoptic", "step"]
# The check fits in 8 minutes of device time, of which the machine's start takes about one.
STAGE_BUDGET_S = 7 * 60


def _dry_run() -> list[tuple[str, int, str]]:
    out = subprocess.run(["bash", str(SCRIPT), "--dry-run"], capture_output=True, text=True, check=True).stdout
    return [(m[1], int(m[2]), m[3]) for m in re.finditer(r"^(\S+)\s+(\d+)s  (.*)$", out, re.M)]


def test_the_dry_run_lists_every_stage_within_one_sessions_budget():
    stages = _dry_run()
    assert [name for name, _, _ in stages] == STAGES
    assert sum(budget for _, budget, _ in stages) <= STAGE_BUDGET_S
    commands = " ".join(command for _, _, command in stages)
    for path in re.findall(r"\b(?:tests|benchmarks)/[\w/]+\.py\b", commands):
        assert (ROOT / path).is_file(), f"gpu_check.sh names {path}, which does not exist"
    assert "--scale 1.0" in commands and "--frames" not in commands  # full resolution, every frame


def test_a_run_without_the_prepared_wheels_says_what_to_do(tmp_path):
    copy = tmp_path / "repo"
    (copy / "benchmarks").mkdir(parents=True)
    (copy / "benchmarks" / "gpu_check.sh").write_text(SCRIPT.read_text())
    done = subprocess.run(["bash", str(copy / "benchmarks" / "gpu_check.sh")], capture_output=True, text=True,
                          env={"PATH": "/usr/bin:/bin", "OUT": str(tmp_path / "out")})
    assert done.returncode == 2 and "--prepare" in done.stderr


def test_an_unknown_option_is_refused():
    done = subprocess.run(["bash", str(SCRIPT), "--fast"], capture_output=True, text=True)
    assert done.returncode == 2 and "--dry-run" in done.stderr


def test_the_step_benchmark_times_fixer4d_and_the_bare_loop_on_the_cpu(benchmark_script, tmp_path):
    bench = benchmark_script("gpu_step")
    out = tmp_path / "step.json"
    assert bench.main(["tiny", "--scale", "0.5", "--gaussians", "300", "--steps", "2", "--device", "cpu",
                       "--out", str(out)]) == 0
    result = json.loads(out.read_text())
    assert result["device"] == "cpu" and result["gaussians"] == 300 and (result["width"], result["height"]) == (32, 24)
    times = result["s_per_step"]
    assert set(times) == {"fixer4d", "fixer4d_same_loss", "bare"} and all(t > 0 for t in times.values())
    # the file's times are rounded to the microsecond, its ratio is of the unrounded ones
    assert result["ratio_to_bare"] == pytest.approx(times["fixer4d_same_loss"] / times["bare"], rel=1e-2)
    assert result["cuda_syncs_per_step"] == dict.fromkeys(times)  # counted on CUDA only


def test_the_step_benchmark_refuses_zero_steps(benchmark_script, tmp_path):
    with pytest.raises(SystemExit):
        benchmark_script("gpu_step").main(["tiny", "--steps", "0", "--out", str(tmp_path / "x.json")])


def test_the_report_gathers_stages_runs_and_the_step(benchmark_script, tmp_path):
    logs = tmp_path / "logs"
    logs.mkdir()
    (logs / "stages.tsv").write_text("build\t0\t71250\t110\ndemo\t124\t90004\t90\n")
    (logs / "demo.log").write_text("x" * 5000 + "stage 1 done")
    run = tmp_path / "demo"
    run.mkdir()
    (run / "stages.json").write_text(json.dumps({"init_mvs": {"key": "a", "seconds": 12.345, "done": True},
                                                 "stage1": {"key": "b", "seconds": 0.0, "done": False}}))
    step = tmp_path / "step.json"
    step.write_text(json.dumps({"ratio_to_bare": 1.4, "machine": {"cpu": "x"}}))
    out = tmp_path / "check.json"
    report = benchmark_script("gpu_check_report")
    assert report.main(["--logs", str(logs), "--step", str(step), "--run", f"demo={run}",
                        "--run", f"panoptic={tmp_path / 'missing'}", "--out", str(out)]) == 0
    result = json.loads(out.read_text())
    build, demo = result["stages"]
    assert build == {"stage": "build", "exit": 0, "seconds": 71.25, "budget_s": 110, "timed_out": False,
                     "log_tail": None}
    assert demo["timed_out"] and demo["log_tail"].endswith("stage 1 done") and len(demo["log_tail"]) == 2000
    assert result["total_seconds"] == 161.25
    assert result["runs"]["demo"] == {"stage_seconds": {"init_mvs": 12.35}, "unfinished": ["stage1"]}
    assert result["runs"]["panoptic"] == {"started": False, "stage_seconds": {}}
    assert result["step"] == {"ratio_to_bare": 1.4}
