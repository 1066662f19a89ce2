"""Does the self-check's fold predict what its choice does to the cameras it never saw?

    python benchmarks/self_check_agreement.py [RESULTS_DIR ...] [--out FILE.json]

Reads the quality bench's result files (``fixer4d bench quality``; default: the opacity decay's
``benchmarks/results/quality_allow_continue`` and the reset's
``benchmarks/results/quality_opacity_reset``, made while the fold trained every candidate) and
pairs, run by run, the fold's gain of *continue* over *skip* (the held-back train camera's PSNR,
``self_check.psnr``) with the same choice's gain on the run's held-out cameras: the "STGS w/ MVS
(matched iterations)" row (the continued model) minus "STGS w/ MVS" (the stage-1 model), each run's
own training. Every run of the bench has both, whatever it decided, so the pairs are not selected by
the decision. *refine* is paired where the run chose it (the Full row then is the refined model).
Reports, per results folder and camera kind (validation / test) and over all: Pearson's correlation
of the two gains, the share of runs where their signs agree, and how often the fold's rule (beat
*skip* by more than the tie margin) picked a candidate that lowered the held-out cameras.
Nothing is trained; the figures are the bench's.
"""
from __future__ import annotations

import argparse
import json
import re
import statistics
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
DEFAULT_DIRS = ("benchmarks/results/quality_allow_continue", "benchmarks/results/quality_opacity_reset")
ROW_STAGE1 = "STGS w/ MVS"
ROW_MATCHED = "STGS w/ MVS (matched iterations)"
ROW_FULL = "Full"
# A result file of one set and seed: <set>_seed<k>.json (test cameras) or <set>_val_seed<k>.json.
_RESULT_NAME = re.compile(r"^(?P<set>.+?)(?P<val>_val)?_seed(?P<seed>\d+)\.json$")


def run_pairs(path: Path) -> dict | None:
    """One result file's pairs: {"set", "seed", "cameras", "decision", "fold": {candidate: gain dB},
    "heldout": {candidate: gain dB}}; None for a file without a fold or the rows."""
    m = _RESULT_NAME.match(path.name)
    if m is None:
        return None
    data = json.loads(path.read_text())
    fold = (data.get("self_check") or {}).get("psnr") or {}
    rows = {r["method"]: r.get("psnr") for r in data.get("rows", []) if r.get("status", "ok") == "ok"}
    if not {"skip", "continue"} <= set(fold) or rows.get(ROW_STAGE1) is None or rows.get(ROW_MATCHED) is None:
        return None
    decision = data["self_check"].get("decision")
    out = {"set": m["set"], "seed": int(m["seed"]), "cameras": "validation" if m["val"] else "test",
           "decision": decision,
           "fold": {"continue": fold["continue"] - fold["skip"]},
           "heldout": {"continue": rows[ROW_MATCHED] - rows[ROW_STAGE1]}}
    if decision == "refine" and "refine" in fold and rows.get(ROW_FULL) is not None:
        out["fold"]["refine"] = fold["refine"] - fold["skip"]
        out["heldout"]["refine"] = rows[ROW_FULL] - rows[ROW_STAGE1]
    return out


def agreement(pairs: list[dict], candidate: str) -> dict:
    """{"n", "correlation", "sign_agreement", "fold_gain_mean", "heldout_gain_mean"} of the runs
    that have ``candidate`` in both."""
    xs = [p["fold"][candidate] for p in pairs if candidate in p["fold"]]
    ys = [p["heldout"][candidate] for p in pairs if candidate in p["heldout"]]
    n = len(xs)
    out = {"n": n, "correlation": None, "sign_agreement": None, "fold_gain_mean": None, "heldout_gain_mean": None}
    if n == 0:
        return out
    out["fold_gain_mean"] = sum(xs) / n
    out["heldout_gain_mean"] = sum(ys) / n
    out["sign_agreement"] = sum((x > 0) == (y > 0) for x, y in zip(xs, ys)) / n
    if n >= 3 and len(set(xs)) > 1 and len(set(ys)) > 1:  # Pearson's r needs both to vary
        out["correlation"] = statistics.correlation(xs, ys)
    return out


def chosen_outcomes(pairs: list[dict]) -> dict:
    """How the runs that left stage 1 (decision continue or refine) fared on the held-out cameras:
    {"left_stage1", "lowered_heldout", "mean_heldout_gain_db"}."""
    moved = [p["heldout"][p["decision"]] for p in pairs if p["decision"] in p["heldout"]]
    return {"left_stage1": len(moved), "lowered_heldout": sum(g < 0 for g in moved),
            "mean_heldout_gain_db": sum(moved) / len(moved) if moved else None}


def summarize(pairs: list[dict]) -> dict:
    """{"continue", "refine": ``agreement``, "chosen": ``chosen_outcomes``} of ``pairs``."""
    return {"continue": agreement(pairs, "continue"), "refine": agreement(pairs, "refine"),
            "chosen": chosen_outcomes(pairs)}


def _line(name: str, kind: str, summary: dict) -> str:
    s, ch = summary["continue"], summary["chosen"]
    corr = "-" if s["correlation"] is None else f"{s['correlation']:+.2f}"
    agree = "-" if s["sign_agreement"] is None else f"{s['sign_agreement']:.0%}"
    return (f"{name:28s} {kind:10s} continue: n={s['n']:2d} correlation {corr}, signs agree {agree}; "
            f"left stage 1 in {ch['left_stage1']} runs, lowered the held-out cameras in {ch['lowered_heldout']}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("dirs", nargs="*", type=Path, default=[ROOT / d for d in DEFAULT_DIRS],
                        help="quality bench result folders")
    parser.add_argument("--out", type=Path, default=None, help="also write the result as JSON")
    args = parser.parse_args(argv)

    result = {"question": __doc__.splitlines()[0], "folders": {}}
    everything = []
    for folder in args.dirs:
        pairs = [p for f in sorted(folder.glob("*_seed*.json")) if (p := run_pairs(f)) is not None]
        if not pairs:
            raise SystemExit(f"{folder}: no quality bench result files with a self-check fold "
                             f"(run `fixer4d bench quality` first)")
        everything += pairs
        name = folder.name
        result["folders"][name] = {kind: summarize([p for p in pairs if p["cameras"] == kind])
                                   for kind in ("validation", "test")}
        result["folders"][name]["runs"] = pairs
        for kind in ("validation", "test"):
            print(_line(name, kind, result["folders"][name][kind]))
    result["all"] = {kind: summarize([p for p in everything if p["cameras"] == kind]) for kind in ("validation", "test")}
    for kind in ("validation", "test"):
        print(_line("all", kind, result["all"][kind]))
    if args.out:
        args.out.write_text(json.dumps(result, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
