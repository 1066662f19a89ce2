"""How long the test suite takes on this machine, run as ``make test`` runs it or another way.

    python benchmarks/suite_time.py LABEL [--out benchmarks/results/suite_time.json] [-- PYTEST_ARGS ...]

Runs ``python -m pytest PYTEST_ARGS`` (default: the Makefile's, a worker per usable CPU) from the
repository's root and records, under LABEL in the result file (other labels kept, so that two ways
of running the same commit sit side by side): the arguments, the thread variables set, the wall
seconds, the CPU seconds of the processes it started, pytest's own seconds and outcome counts,
the commit and the machine. ``make test`` times the same command plus
the install check. Time it on an idle machine, one run at a time: the suite uses every core.
"""
from __future__ import annotations

import argparse
import json
import os
import re
import resource
import shlex
import subprocess
import sys
import time
from datetime import datetime, timezone
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from fixer4d.atomic import write_json  # noqa: E402
from fixer4d.bench.machine import machine_info  # noqa: E402
from fixer4d.pipeline.run_folder import source_commit  # noqa: E402

# Set by the caller, they are the pools' sizes in every worker (tests/pools.py splits only the unset).
THREAD_VARS = ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS")


def makefile_pytest_args(makefile: Path = ROOT / "Makefile") -> list[str]:
    """The Makefile's default ``PYTEST_ARGS``: what ``make test`` passes to pytest."""
    match = re.search(r"^PYTEST_ARGS\s*\?=(.*)$", makefile.read_text(), flags=re.MULTILINE)
    return shlex.split(match.group(1)) if match else []


def summary_counts(output: str) -> dict:
    """pytest's closing line ("== 3 passed, 1 skipped in 4.20s ==", bare under ``-q``) as
    {"passed": 3, "skipped": 1, "pytest_seconds": 4.2}; empty where the output has none."""
    lines = [line for line in output.splitlines()
             if re.search(r"\d+ (passed|failed|skipped|errors?)\b.* in [0-9.]+s\b", line)]
    if not lines:
        return {}
    last = lines[-1]
    counts = {word: int(n) for n, word in re.findall(r"(\d+) (passed|failed|skipped|errors?|xfailed|xpassed)", last)}
    seconds = re.search(r"\bin ([0-9.]+)s\b", last)
    return {**counts, "pytest_seconds": float(seconds.group(1))}


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    ours, pytest_args = (argv[:argv.index("--")], argv[argv.index("--") + 1:]) if "--" in argv else (argv, None)
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("label", help="the name of this way of running the suite in the result file")
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks/results/suite_time.json")
    args = parser.parse_args(ours)
    pytest_args = makefile_pytest_args() if pytest_args is None else pytest_args
    machine, commit = machine_info(), source_commit()  # before the run: the code it tests
    cpu0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    done = subprocess.run([sys.executable, "-m", "pytest", "-p", "no:cacheprovider", *pytest_args], cwd=ROOT,
                          capture_output=True, text=True)
    wall = time.perf_counter() - t0
    cpu1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (cpu1.ru_utime - cpu0.ru_utime) + (cpu1.ru_stime - cpu0.ru_stime)
    summary = summary_counts(done.stdout)
    record = {"pytest_args": pytest_args, "wall_seconds": round(wall, 1), "cpu_seconds": round(cpu, 1), **summary,
              "returncode": done.returncode, "thread_env": {k: os.environ.get(k) for k in THREAD_VARS},
              "commit": commit, "date": datetime.now(timezone.utc).strftime("%Y-%m-%d"),
              "machine": machine}
    results = json.loads(args.out.read_text()) if args.out.is_file() else {}
    results.setdefault("runs", {})[args.label] = record
    results["command"] = "python benchmarks/suite_time.py LABEL [-- PYTEST_ARGS]"
    write_json(args.out, results)
    print(f"{args.label}: {wall:.0f} s wall, {summary or 'no pytest summary'} -> {args.out}")
    if done.returncode != 0:
        print(done.stdout[-3000:], done.stderr[-2000:], sep="\n", file=sys.stderr)
    return done.returncode


if __name__ == "__main__":
    sys.exit(main())
