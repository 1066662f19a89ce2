"""Pseudo-views where the model is undetermined (``trajectories.undetermined_views``), measured on
finished quality-bench runs without re-running stage 1 (docs/decisions/undetermined-views.md).

    python benchmarks/undetermined_views.py SET --seeds 0,1,2 --views 4 --runs DIR [--measure] --out FILE
        [--base-runs runs/quality --base-out benchmarks/results/quality] [--set KEY=VALUE --label L]
        [--control-label C]

SET is a quality-bench camera set (panoptic, panoptic_c, demo). ``--measure`` copies each seed's
run ``runs/quality/SET/seed<S>`` to ``DIR/SET/seed<S>_k<K>``, runs stage 2 there with the views
(``fixer4d refine --set trajectories.undetermined_views=K --set self_check.enabled=false``: stage 2
forced, so Full is stage 2's model), and evaluates it on the set's validation cameras. Without
``--measure`` the script reads what is there. The K = 0 control is a copy refined the same way
(``--views 0``), or, where the baseline's self-check chose refine, the baseline's own Full.

The result file holds, per seed, the validation rows (PSNR, PSNR on unobserved pixels, LPIPS), and
the paired differences with ``fixer4d.stats.interval``: k − k = 0, k − STGS w/ MVS, k − the
matched-iterations control (as much plain training) and k − the baseline's Full (the self-check's
choice). It also holds the same figures on the test cameras
(reported beside, never chosen on) and stage 2's seconds. ``--base-runs`` / ``--base-out``:
another quality bench's runs and result files as the base (an option's, e.g. the opacity decay's
``runs/quality_decay``).
"""
from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

from fixer4d.bench.quality import DATA_ROOT, DEFAULT_OUT, DEFAULT_RUNS, REPO_ROOT, ROW_FULL, ROW_MATCHED, ROW_MVS
from fixer4d.stats import interval

VALIDATION = {"panoptic": DATA_ROOT / "panoptic_basketball_val", "panoptic_c": DATA_ROOT / "panoptic_basketball_c_val",
              "demo": Path("demo_val")}
METRICS = ("psnr", "psnr_unobserved", "lpips")


def _rows(report: dict[str, Any]) -> dict[str, dict[str, Any]]:
    return {r["method"]: r for r in report["rows"] if r.get("status") == "ok"}


def _refined(run: Path) -> bool:
    stages = run / "stages.json"
    return stages.is_file() and bool(json.loads(stages.read_text()).get("stage2", {}).get("done"))


def measure(name: str, seed: int, views: int, runs: Path, base_runs: Path = REPO_ROOT / DEFAULT_RUNS,
            settings: tuple[str, ...] = (), label: str = "") -> Path:
    """Copy the seed's finished run, refine it with ``views`` views and ``settings`` (KEY=VALUE;
    stage 2 forced), evaluate it on the validation cameras; returns the copy
    (``seed<S>_k<K><label>``)."""
    run = runs / name / f"seed{seed}_k{views}{label}"
    if not run.exists():
        run.parent.mkdir(parents=True, exist_ok=True)
        shutil.copytree(base_runs / name / f"seed{seed}", run)
    cli = [sys.executable, "-m", "fixer4d.cli"]
    extra = [a for kv in settings for a in ("--set", kv)]
    subprocess.run([*cli, "refine", str(run), "--set", f"trajectories.undetermined_views={views}", *extra,
                    "--set", "self_check.enabled=false", "--quiet"], check=True)
    subprocess.run([*cli, "eval", str(run), "--cameras-from", str(VALIDATION[name]), "--quiet"], check=True)
    return run


def _stage2(run: Path, report: Path) -> dict[str, Any] | None:
    """Full's metrics and stage 2's seconds of a refined copy, None when it has not been refined."""
    if not (_refined(run) and report.is_file()):
        return None
    full = _rows(json.loads(report.read_text()))[ROW_FULL]
    seconds = json.loads((run / "stages.json").read_text())["stage2"]["seconds"]
    return {**{m: full.get(m) for m in METRICS}, "seconds": seconds}


def seed_figures(name: str, seed: int, views: int, runs: Path, split: str,
                 base_out: Path = DEFAULT_OUT, label: str = "", control_label: str = "") -> dict[str, Any] | None:
    """The rows of one seed on ``split`` ("val" or "test"): the baseline's, stage 2 with the views
    (the copy ``seed<S>_k<K><label>``) and the control ``seed<S>_k0<control_label>`` (None where
    not measured)."""
    suffix = "_val" if split == "val" else ""
    base = json.loads((base_out / f"{name}{suffix}_seed{seed}.json").read_text())
    rows = _rows(base)

    def report(folder: str) -> Path:
        run = runs / name / folder
        return run / "heldout" / VALIDATION[name].name / "report.json" if split == "val" else run / "report.json"

    variant = f"seed{seed}_k{views}{label}"
    with_views = _stage2(runs / name / variant, report(variant))
    if with_views is None:
        return None
    control = _stage2(runs / name / f"seed{seed}_k0{control_label}", report(f"seed{seed}_k0{control_label}"))
    if control is None and not control_label and base.get("self_check", {}).get("decision") == "refine":
        control = {**{m: rows[ROW_FULL].get(m) for m in METRICS}, "seconds": None}  # the baseline's Full is stage 2
    return {"decision": base.get("self_check", {}).get("decision"),
            "mvs": {m: rows[ROW_MVS].get(m) for m in METRICS}, "baseline_full": {m: rows[ROW_FULL].get(m) for m in METRICS},
            "matched": {m: rows[ROW_MATCHED].get(m) for m in METRICS} if ROW_MATCHED in rows else None,
            "views": with_views, "control": control}


def paired(per_seed: dict[str, dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """Per metric, the paired differences over seeds (``fixer4d.stats.interval``)."""
    out = {}
    for m in METRICS:
        def diff(a: str, b: str) -> dict[str, Any]:
            return interval([s[a][m] - s[b][m] for s in per_seed.values()
                             if s.get(a) and s.get(b) and s[a].get(m) is not None and s[b].get(m) is not None])

        out[m] = {"views - control": diff("views", "control"), "views - STGS w/ MVS": diff("views", "mvs"),
                  "views - baseline Full": diff("views", "baseline_full"), "views - matched": diff("views", "matched"),
                  "control - STGS w/ MVS": diff("control", "mvs"),
                  "baseline Full - STGS w/ MVS": diff("baseline_full", "mvs"),
                  "views": interval([s["views"][m] for s in per_seed.values()]),
                  "control": interval([s["control"][m] for s in per_seed.values() if s.get("control")])}
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("set", choices=sorted(VALIDATION))
    parser.add_argument("--seeds", default="0,1,2")
    parser.add_argument("--views", type=int, default=4, help="trajectories.undetermined_views (0 = the control)")
    parser.add_argument("--runs", type=Path, required=True, help="where the copies of the runs go (outside git)")
    parser.add_argument("--measure", action="store_true", help="copy, refine and evaluate before reading")
    parser.add_argument("--set", dest="settings", action="append", default=[], metavar="KEY=VALUE",
                        help="a further stage-2 setting of the variant (repeatable); its copies get --label")
    parser.add_argument("--label", default="", help="suffix of the variant's copies (seed<S>_k<K><label>)")
    parser.add_argument("--control-label", default="", help="suffix of the control's copies (default: the "
                        "k = 0 control, seed<S>_k0), e.g. an earlier variant's --label")
    parser.add_argument("--out", type=Path, help="the result JSON")
    parser.add_argument("--base-runs", type=Path, default=REPO_ROOT / DEFAULT_RUNS,
                        help="the quality bench's run folders the copies start from (default runs/quality)")
    parser.add_argument("--base-out", type=Path, default=DEFAULT_OUT,
                        help="that bench's result files (default benchmarks/results/quality)")
    args = parser.parse_args()
    seeds = [int(s) for s in args.seeds.split(",")]
    if args.settings and not args.label:
        parser.error("--set needs --label: the variant's copies must not be the k = 0 control's")
    if args.measure:
        for seed in seeds:
            measure(args.set, seed, args.views, args.runs, args.base_runs, tuple(args.settings), args.label)
    result: dict[str, Any] = {"set": args.set, "views": args.views, "settings": args.settings,
                              "control_label": args.control_label,
                              "command": " ".join(sys.argv)}
    for split in ("val", "test"):
        per_seed = {str(s): f for s in seeds
                    if (f := seed_figures(args.set, s, args.views, args.runs, split, args.base_out, args.label,
                                          args.control_label))}
        result[split] = {"seeds": per_seed, "paired": paired(per_seed)}
    for split in ("val", "test"):
        for label, iv in result[split]["paired"]["psnr"].items():
            if iv["mean"] is not None:
                ci = "n/a" if iv["ci95"] is None else f"{iv['ci95']:.2f}"
                print(f"{split:4s} psnr {label:28s} {iv['mean']:+.2f} ± {ci}  {[round(v, 3) for v in iv['values']]}")
    if args.out is not None:
        from fixer4d.atomic import write_json

        write_json(args.out, result)
    return 0


if __name__ == "__main__":
    sys.exit(main())
