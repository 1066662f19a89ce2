"""What a self-check's decisions would have delivered, scored with stage 2 forced on the same runs.

    python benchmarks/fold_decisions.py --forced DIR --folds DIR [--quality DIR] --out FILE.json
    python benchmarks/fold_decisions.py --folds DIR --own-folds DIR [--quality DIR] --out FILE.json

Stage 2 does not depend on the check's decision, so a run's Full under any check is known once
stage 2 has been forced on it: *refine* delivers the forced Full, *skip* the stage-1 model (STGS w/
MVS). ``--forced``: ``forced_<SET>.json`` of ``benchmarks/undetermined_views.py --views 0`` (stage 2
forced, seeds' validation and test rows). ``--folds``: ``<SET>_seed<S>.json`` of
``benchmarks/self_check_folds.py`` (the check under other settings on the same runs).
``--quality``: the quality bench's result files of those runs (their own check's decision and
stage seconds). Per set and split it writes each seed's decisions, the forced gain, Full −
STGS w/ MVS under either check with its interval, and the variant check's share of the run (its
wall seconds over the run's stages with the run's own check replaced by it).

Without ``--forced`` only the seeds whose Full is known under both checks are scored: both skip
(0), or the run itself refined (its quality record's Full is stage 2's); the others are listed as
unscored. ``--own-folds``: ``<SET>_seed<S>.json`` of ``self_check_folds.py`` at the run's own
settings, the own decision of a seed that has no quality record (a config-only folder), whose
Full − STGS w/ MVS is then 0 where both skip and unknown otherwise. Every seed also gets the
variant check's CPU seconds over its own check's, where both were measured in one way.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from fixer4d.bench.quality import DEFAULT_OUT
from fixer4d.stats import interval

SETS = ("demo", "panoptic", "panoptic_c")


def _seed_figures(name: str, split: str, seed: str, folds: Path, own_folds: Path | None,
                  quality: list[Path], forced_rows: dict[str, Any] | None) -> dict[str, Any] | None:
    """One seed's decisions and what each check delivers (None: no variant fold for it, or no own
    decision). The own decision comes from ``own_folds`` where it has the seed, else from the first
    quality folder holding its record."""
    fold_file = folds / f"{name}_seed{seed}.json"
    if not fold_file.is_file():
        return None
    fold = json.loads(fold_file.read_text())
    own_fold_file = own_folds / f"{name}_seed{seed}.json" if own_folds is not None else None
    own_fold = json.loads(own_fold_file.read_text()) if own_fold_file is not None and own_fold_file.is_file() else None
    record = None
    if own_fold is None:
        record_name = f"{name}{'_val' if split == 'val' else ''}_seed{seed}.json"
        record_file = next((q / record_name for q in quality if (q / record_name).is_file()), None)
        record = json.loads(record_file.read_text()) if record_file is not None else None
    if record is None and own_fold is None:
        return None
    own_decision = record["self_check"]["decision"] if record is not None else own_fold["decision"]
    variant_decision = fold["decision"]
    if forced_rows is not None and forced_rows.get("views"):
        gain = forced_rows["views"]["psnr"] - forced_rows["mvs"]["psnr"]
    elif record is not None and own_decision == "refine":
        rows = {r["method"]: r for r in record["rows"]}
        gain = rows["Full"]["psnr"] - rows["STGS w/ MVS"]["psnr"]
    else:
        gain = None
    figures: dict[str, Any] = {"forced_gain_db": gain, "own_decision": own_decision,
                               "variant_decision": variant_decision,
                               "variant_gain_db": fold["gains"].get("refine", {}).get("gain_db"),
                               "variant_check_s": fold["check_wall_s"], "variant_check_cpu_s": fold.get("check_cpu_s")}
    if own_fold is not None and own_fold.get("check_cpu_s") and fold.get("check_cpu_s"):
        figures["variant_over_own_cpu"] = fold["check_cpu_s"] / own_fold["check_cpu_s"]
    if fold.get("run_stages_s"):
        stages = float(fold["run_stages_s"])
        figures.update(own_check_s=fold["run_check_s"], own_share=fold["run_check_s"] / stages,
                       variant_share=fold["check_wall_s"] / (stages - fold["run_check_s"] + fold["check_wall_s"]))
    return figures


def score_set(name: str, forced: dict[str, Any] | None, folds: Path, quality: list[Path],
              own_folds: Path | None = None) -> dict[str, Any]:
    """The figures of one camera set (module docstring); seeds without a variant fold are left out."""
    out: dict[str, Any] = {}
    for split in ("val", "test"):
        seeds, unscored, own, variant = {}, [], [], []
        if forced is not None:
            candidates = sorted(forced[split]["seeds"], key=int)
        else:
            candidates = sorted({p.stem.rsplit("_seed", 1)[1] for p in folds.glob(f"{name}_seed*.json")
                                 if p.stem.rsplit("_seed", 1)[0] == name}, key=int)
        for seed in candidates:
            rows = forced[split]["seeds"][seed] if forced is not None else None
            fig = _seed_figures(name, split, seed, folds, own_folds, quality, rows)
            if fig is None or (forced is not None and not (rows or {}).get("views")):
                continue
            decisions = (fig["own_decision"], fig["variant_decision"])
            if fig["forced_gain_db"] is None and "refine" in decisions:
                unscored.append(seed)
                continue
            seeds[seed] = fig
            own.append(fig["forced_gain_db"] if decisions[0] == "refine" else 0.0)
            variant.append(fig["forced_gain_db"] if decisions[1] == "refine" else 0.0)
        out[split] = {"seeds": seeds, "unscored": unscored, "own_full_minus_mvs": interval(own),
                      "variant_full_minus_mvs": interval(variant),
                      "variant_minus_own": interval([v - o for v, o in zip(variant, own)]),
                      "forced_full_minus_mvs": interval([s["forced_gain_db"] for s in seeds.values()
                                                         if s["forced_gain_db"] is not None])}
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--forced", type=Path, default=None, help="folder of forced_<SET>.json")
    parser.add_argument("--folds", type=Path, required=True, help="folder of <SET>_seed<S>.json")
    parser.add_argument("--own-folds", type=Path, default=None,
                        help="folder of <SET>_seed<S>.json: folds at the runs' own settings")
    parser.add_argument("--quality", type=Path, action="append", default=None,
                        help=f"a folder of the runs' quality-bench result files (repeatable, first match; "
                             f"default {DEFAULT_OUT})")
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args(argv)
    args.quality = args.quality or [DEFAULT_OUT]
    doc: dict[str, Any] = {"command": "python benchmarks/fold_decisions.py " + " ".join(sys.argv[1:] if argv is None else argv), "sets": {}}
    for name in SETS:
        if args.forced is None:
            if any(args.folds.glob(f"{name}_seed*.json")):
                doc["sets"][name] = score_set(name, None, args.folds, args.quality, args.own_folds)
            continue
        forced = args.forced / f"forced_{name}.json"
        if forced.is_file():
            doc["sets"][name] = score_set(name, json.loads(forced.read_text()), args.folds, args.quality,
                                          args.own_folds)
    if not doc["sets"]:
        print(f"no set of {', '.join(SETS)} to score: give --forced with forced_<SET>.json, or folds of these sets")
        return 2
    everything = [v for s in doc["sets"].values() for v in s["val"]["variant_full_minus_mvs"]["values"]]
    theirs = [v for s in doc["sets"].values() for v in s["val"]["own_full_minus_mvs"]["values"]]
    doc["validation_all"] = {"own": interval(theirs), "variant": interval(everything),
                             "variant_minus_own": interval([v - o for v, o in zip(everything, theirs)]),
                             "unscored": {n: s["val"]["unscored"] for n, s in doc["sets"].items() if s["val"]["unscored"]},
                             "variant_share_max": max((r["variant_share"] for s in doc["sets"].values()
                                                       for r in s["val"]["seeds"].values() if "variant_share" in r),
                                                  default=None)}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(doc, indent=1) + "\n")
    for name, s in doc["sets"].items():
        v = s["val"]
        print(f"{name}: validation Full - STGS w/ MVS, own check {v['own_full_minus_mvs']['mean']:+.2f}, "
              f"variant {v['variant_full_minus_mvs']['mean']:+.2f}, forced {v['forced_full_minus_mvs']['mean'] or 0:+.2f} dB"
              + (f"; unscored seeds {', '.join(v['unscored'])}" if v["unscored"] else ""))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
