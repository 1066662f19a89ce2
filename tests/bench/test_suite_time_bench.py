"""benchmarks/suite_time.py: the suite's time under a label, other labels kept."""
from __future__ import annotations

import json


def test_reads_the_makefiles_arguments_and_pytests_closing_line(benchmark_script):
    suite = benchmark_script("suite_time")
    assert "-n" in suite.makefile_pytest_args()  # make test runs a worker per CPU
    out = "....\n=========== 1208 passed, 9 skipped, 2 warnings in 754.05s (0:12:34) ============\n"
    assert suite.summary_counts(out) == {"passed": 1208, "skipped": 9, "pytest_seconds": 754.05}
    assert suite.summary_counts("== 1 failed, 2 passed, 1 error in 3.5s ==")["failed"] == 1
    assert suite.summary_counts("INTERNALERROR> no summary") == {}


def test_times_a_run_and_keeps_the_other_labels(benchmark_script, tmp_path):
    suite = benchmark_script("suite_time")
    out = tmp_path / "suite_time.json"
    out.write_text(json.dumps({"runs": {"earlier": {"wall_seconds": 1.0}}}))
    args = ["-q", "-p", "no:xdist", "tests/test_atomic.py"]
    assert suite.main(["one process", "--out", str(out), "--", *args]) == 0
    runs = json.loads(out.read_text())["runs"]
    assert runs["earlier"] == {"wall_seconds": 1.0}
    ran = runs["one process"]
    assert ran["pytest_args"] == args and ran["passed"] > 0 and ran["returncode"] == 0
    assert ran["wall_seconds"] >= ran["pytest_seconds"] > 0 and ran["cpu_seconds"] > 0
    assert ran["machine"]["usable_cpus"] >= 1 and set(ran["thread_env"]) == {"NUMBA_NUM_THREADS", "OMP_NUM_THREADS"}
