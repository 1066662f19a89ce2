"""What a self-check's decisions would have delivered, scored with stage 2 forced on the same runs.

    python benchmarks/fold_decisions.py --forced DIR --folds DIR [--quality DIR] --out FILE.json

Stage 2 does not depend on the check's decision, so a run's Full under any check is known once
stage 2 has been forced on it: *refine* delivers the forced Full, *skip* the stage-1 model (STGS w/
MVS). ``--forced``: ``forced_<SET>.json`` of ``benchmarks/undetermined_views.py --views 0`` (stage 2
forced, seeds' validation and test rows). ``--folds``: ``<SET>_seed<S>.json`` of
``benchmarks/self_check_folds.py`` (the check under other settings on the same runs).
``--quality``: the quality bench's result files of those runs (their own check's decision and
stage seconds). Per set and split it writes each seed's decisions, the forced gain, Full −
STGS w/ MVS under either check with its interval, and the variant check's share of the run (its
wall seconds over the run's stages with the run's own check replaced by it).
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from fixer4d.bench.quality import DEFAULT_OUT
from fixer4d.stats import interval

SETS = ("demo", "panoptic", "panoptic_c")


def score_set(name: str, forced: dict[str, Any], folds: Path, quality: Path) -> dict[str, Any]:
    """The figures of one camera set (module docstring); seeds without a variant fold are left out."""
    out: dict[str, Any] = {}
    for split in ("val", "test"):
        seeds, own, variant = {}, [], []
        for seed, rows in sorted(forced[split]["seeds"].items(), key=lambda kv: int(kv[0])):
            fold_file = folds / f"{name}_seed{seed}.json"
            if not fold_file.is_file() or not rows.get("views"):
                continue
            fold = json.loads(fold_file.read_text())
            record = json.loads((quality / f"{name}{'_val' if split == 'val' else ''}_seed{seed}.json").read_text())
            gain = rows["views"]["psnr"] - rows["mvs"]["psnr"]
            own_decision, variant_decision = record["self_check"]["decision"], fold["decision"]
            stages = float(fold["run_stages_s"])
            share = fold["check_wall_s"] / (stages - fold["run_check_s"] + fold["check_wall_s"])
            seeds[seed] = {"forced_gain_db": gain, "own_decision": own_decision, "variant_decision": variant_decision,
                           "variant_gain_db": fold["gains"].get("refine", {}).get("gain_db"),
                           "variant_check_s": fold["check_wall_s"], "own_check_s": fold["run_check_s"],
                           "variant_share": share, "own_share": fold["run_check_s"] / stages}
            own.append(gain if own_decision == "refine" else 0.0)
            variant.append(gain if variant_decision == "refine" else 0.0)
        out[split] = {"seeds": seeds, "own_full_minus_mvs": interval(own), "variant_full_minus_mvs": interval(variant),
                      "forced_full_minus_mvs": interval([s["forced_gain_db"] for s in seeds.values()])}
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--forced", type=Path, required=True, help="folder of forced_<SET>.json")
    parser.add_argument("--folds", type=Path, required=True, help="folder of <SET>_seed<S>.json")
    parser.add_argument("--quality", type=Path, default=DEFAULT_OUT, help="the runs' quality-bench result files")
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args(argv)
    doc: dict[str, Any] = {"command": "python benchmarks/fold_decisions.py " + " ".join(argv or []), "sets": {}}
    for name in SETS:
        forced = args.forced / f"forced_{name}.json"
        if forced.is_file():
            doc["sets"][name] = score_set(name, json.loads(forced.read_text()), args.folds, args.quality)
    if not doc["sets"]:
        print(f"{args.forced}: no forced_<SET>.json of {', '.join(SETS)}")
        return 2
    everything = [v for s in doc["sets"].values() for v in s["val"]["variant_full_minus_mvs"]["values"]]
    theirs = [v for s in doc["sets"].values() for v in s["val"]["own_full_minus_mvs"]["values"]]
    doc["validation_all"] = {"own": interval(theirs), "variant": interval(everything),
                             "variant_share_max": max((r["variant_share"] for s in doc["sets"].values()
                                                       for r in s["val"]["seeds"].values()), default=None)}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(doc, indent=1) + "\n")
    for name, s in doc["sets"].items():
        v = s["val"]
        print(f"{name}: validation Full - STGS w/ MVS, own check {v['own_full_minus_mvs']['mean']:+.2f}, "
              f"variant {v['variant_full_minus_mvs']['mean']:+.2f}, forced {v['forced_full_minus_mvs']['mean']:+.2f} dB")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
