"""Stage-1 options scored against the quality bench's runs of the same seeds.

    python benchmarks/stage1_against_quality.py RUN [RUN ...] [--quality DIR] --out FILE.json

Each RUN is stage 1 of a quality-bench set under an option, at the bench's settings and one of its
seeds, scored on both camera splits::

    fixer4d run SCENE --seed S [the set's flags] --no-baseline --rounds 0 --set self_check.enabled=false --set KEY=VALUE
    fixer4d eval RUN --cameras-from VALIDATION

Its STGS w/ MVS row (test cameras: RUN/report.json; validation: RUN/heldout/<VALIDATION>/report.json)
is paired with the quality result file of the same set and seed (``--quality``, default
benchmarks/results/quality/), whose stage 1 ran without the option. On the host and packages that
made those files stage 1 is deterministic, so the difference is the option's alone; elsewhere it
mixes in the host's draw (the files record both). The option is what the run's configuration sets
beyond the quality run's, its stage-2 and check switches aside. Writes each run's rows and
differences (PSNR, LPIPS) and, per option and set, their mean ± 95 % interval over seeds.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from fixer4d.bench.quality import DEFAULT_OUT, ROW_MVS, camera_sets
from fixer4d.pipeline import config_tree
from fixer4d.pipeline.config import RunConfig
from fixer4d.stats import interval

# Keys a stage-1-only run sets apart from the option under test (no baseline, no stage 2, no check).
STAGE1_ONLY = ("baseline_sparse", "stage2.rounds", "self_check.enabled")
METRICS = ("psnr", "lpips")


def _row(report: Path) -> dict[str, Any]:
    rows = json.loads(report.read_text())["rows"]
    found = [r for r in rows if r["method"] == ROW_MVS and r.get("status", "ok") == "ok"]
    if not found:
        raise SystemExit(f"{report}: no {ROW_MVS!r} row")
    return found[0]


def _set_of(source: str) -> Any:
    for cs in camera_sets().values():
        if Path(cs.scene).name == Path(source).name and cs.validation is not None:
            return cs
    raise SystemExit(f"{source}: not the scene of a quality-bench set with validation cameras")


def score_run(run: Path, quality: Path) -> dict[str, Any]:
    """One RUN against its quality file: the option, both splits' rows and their differences."""
    config = json.loads((run / "config.json").read_text())["config"]
    cs, seed = _set_of(config["scene"]["source"]), config["training"]["seed"]
    base_test = json.loads((quality / f"{cs.name}_seed{seed}.json").read_text())
    base_val = json.loads((quality / f"{cs.name}_val_seed{seed}.json").read_text())
    # both trees with every default filled in: a key newer than the quality files is no difference
    option = [c for c in config_tree.diff(RunConfig.from_dict(base_test["config"]["config"]).to_dict(),
                                          RunConfig.from_dict(config).to_dict())
              if not c.startswith(STAGE1_ONLY) and not c.startswith("scene.")]
    out = {"run": str(run), "set": cs.name, "seed": seed, "option": option, "splits": {}}
    for split, report, base in (("test", run / "report.json", base_test),
                                ("validation", run / "heldout" / Path(cs.validation).name / "report.json", base_val)):
        row = _row(report)
        base_row = [r for r in base["rows"] if r["method"] == ROW_MVS][0]
        out["splits"][split] = {m: {"option": row.get(m), "base": base_row.get(m),
                                    "difference": None if row.get(m) is None or base_row.get(m) is None
                                    else row[m] - base_row[m]} for m in METRICS}
    return out


def summarize(scored: list[dict[str, Any]]) -> dict[str, Any]:
    """{option: {set: {split: {metric: interval of the differences over seeds}}}}."""
    groups: dict[str, dict[str, list[dict[str, Any]]]] = {}
    for s in scored:
        groups.setdefault("; ".join(s["option"]) or "(none)", {}).setdefault(s["set"], []).append(s)
    return {opt: {name: {"seeds": sorted(s["seed"] for s in runs),
                         **{split: {m: interval([s["splits"][split][m]["difference"] for s in runs]) for m in METRICS}
                            for split in ("validation", "test")}}
                  for name, runs in sets.items()}
            for opt, sets in groups.items()}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs="+", type=Path, help="stage-1-only run folders, each evaluated on validation")
    parser.add_argument("--quality", type=Path, default=DEFAULT_OUT, help="the quality bench's result files")
    parser.add_argument("--out", type=Path, required=True, help="result JSON")
    args = parser.parse_args(argv)
    scored = [score_run(run, args.quality) for run in args.runs]
    result = {"quality": str(args.quality), "runs": scored, "summary": summarize(scored)}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=1) + "\n")
    for opt, sets in result["summary"].items():
        for name, s in sets.items():
            v, t = s["validation"]["psnr"], s["test"]["psnr"]
            ci = "" if v["ci95"] is None else f" ± {v['ci95']:.2f}"
            print(f"{opt} | {name} seeds {s['seeds']}: validation {v['mean']:+.2f}{ci} dB, test {t['mean']:+.2f} dB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
