"""The result file of benchmarks/gpu_check.sh: every stage's exit status and seconds, the step
against the bare gsplat loop, each run's per-stage seconds (RUN/stages.json: the stages that
finished, and the one a budget cut short) and rows, the CUDA tests' summary line and the tail of
each stage's log, with the GPU and the library versions.

    python benchmarks/gpu_check_report.py --logs DIR --step STEP.json --run NAME=RUN ... --out FILE.json
"""
from __future__ import annotations

import argparse
import importlib.metadata
import json
from pathlib import Path

from fixer4d.atomic import write_json

# Characters of each stage's log kept in the result (its end: the error, or the summary).
LOG_TAIL_CHARS = 2000
# `timeout`'s exit status when the budget ran out.
TIMED_OUT = 124


def read_stages(tsv: Path) -> list[dict]:
    """The rows ``stage`` of gpu_check.sh wrote: name, exit status, milliseconds, budget."""
    rows = []
    for line in tsv.read_text().splitlines() if tsv.exists() else []:
        name, rc, ms, budget = line.split("\t")
        rows.append({"stage": name, "exit": int(rc), "seconds": round(int(ms) / 1000, 2), "budget_s": int(budget),
                     "timed_out": int(rc) == TIMED_OUT})
    return rows


def run_summary(run: Path) -> dict:
    """A run folder's finished stages with their seconds, the stage it was in when it stopped,
    and its rows where report.json was written."""
    if not (run / "stages.json").exists():
        return {"started": run.exists(), "stage_seconds": {}}
    records = json.loads((run / "stages.json").read_text())
    out = {"stage_seconds": {k: round(float(r["seconds"]), 2) for k, r in records.items() if r.get("done")},
           "unfinished": [k for k, r in records.items() if not r.get("done")]}
    if (run / "report.json").exists():
        report = json.loads((run / "report.json").read_text())
        out["rows"] = [{k: r.get(k) for k in ("method", "status", "psnr", "psnr_dynamic", "lpips")}
                       for r in report.get("rows", [])]
    return out


def versions() -> dict:
    out = {}
    for name in ("torch", "gsplat", "numpy", "numba"):
        try:
            out[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            out[name] = None
    try:
        import torch

        out["gpu"] = torch.cuda.get_device_name(0) if torch.cuda.is_available() else None
        out["cuda"] = torch.version.cuda
    except ImportError:
        pass
    return out


def pytest_summary(log: Path) -> str | None:
    """The last line of a pytest log that counts passed / failed tests."""
    lines = [s for s in log.read_text(errors="replace").splitlines() if " passed" in s or " failed" in s] \
        if log.exists() else []
    return lines[-1].strip("= ") if lines else None


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--logs", type=Path, required=True, help="gpu_check.sh's log folder (stages.tsv, NAME.log)")
    parser.add_argument("--step", type=Path, required=True, help="benchmarks/gpu_step.py's result file")
    parser.add_argument("--run", action="append", default=[], metavar="NAME=RUN", help="a run folder of the check")
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args(argv)

    stages = read_stages(args.logs / "stages.tsv")
    for row in stages:
        log = args.logs / f"{row['stage']}.log"
        row["log_tail"] = log.read_text(errors="replace")[-LOG_TAIL_CHARS:] if log.exists() else None
    runs = {}
    for spec in args.run:
        name, _, path = spec.partition("=")
        if not path:
            parser.error(f"--run {spec!r}: expected NAME=RUN")
        runs[name] = run_summary(Path(path))
    step = json.loads(args.step.read_text()) if args.step.exists() else None
    if step is not None:
        step.pop("machine", None)
    result = {"stages": stages, "total_seconds": round(sum(r["seconds"] for r in stages), 2),
              "tests": pytest_summary(args.logs / "tests.log"), "step": step, "runs": runs, "versions": versions()}
    write_json(args.out, result)
    for row in stages:
        print(f"{row['stage']:9s} exit {row['exit']:3d} {row['seconds']:8.1f} s of {row['budget_s']} s")
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
