"""Does `make run` give the results table's demo seed 0? Runs make run's command into an empty
folder and compares every row with the quality bench's result file.

    python benchmarks/demo_reproduction.py [--run DIR] [--against benchmarks/results/quality/demo_seed0.json]
        [--out benchmarks/results/demo_reproduction.json] [--set KEY=VALUE ...]

DIR (default a fresh temporary folder) must not hold a run: a resumed run would reuse stages and
say nothing about reproducing them. ``--set`` adds settings to the command (then compare
``--against`` a file made under them). The result file is the bench's record of the run
(``fixer4d.bench.quality.record_run``) with ``compared_with``: the file, its commit, and per row
the two PSNRs and whether they are identical. Time it on an idle machine: the stage seconds are
part of the record.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from fixer4d.atomic import write_json  # noqa: E402
from fixer4d.bench.quality import record_run  # noqa: E402

COMMAND = ("run", "demo")  # the Makefile's `run` target: fixer4d run demo --out $(RUN)


def compare(rows: list[dict], reference: list[dict]) -> dict[str, dict]:
    """Per method of ``reference``: {"psnr", "reference_psnr", "identical"} (a missing row: None)."""
    ours = {r["method"]: r.get("psnr") for r in rows}
    return {r["method"]: {"psnr": ours.get(r["method"]), "reference_psnr": r.get("psnr"),
                          "identical": ours.get(r["method"]) == r.get("psnr")} for r in reference}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--run", type=Path, default=None, help="an empty folder for the run (default: a temporary one)")
    parser.add_argument("--against", type=Path, default=ROOT / "benchmarks/results/quality/demo_seed0.json")
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks/results/demo_reproduction.json")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE", dest="settings",
                        help="a setting added to make run's command (repeatable)")
    args = parser.parse_args(argv)
    extra = [a for kv in args.settings for a in ("--set", kv)]
    with tempfile.TemporaryDirectory(prefix="fixer4d-demo-") as tmp:
        run = args.run if args.run is not None else Path(tmp) / "demo"
        if run.exists() and any(run.iterdir()):
            parser.error(f"{run} is not empty: a resumed run reproduces nothing")
        subprocess.run([sys.executable, "-m", "fixer4d.cli", *COMMAND, "--out", str(run), *extra, "--quiet"],
                       check=True)
        shown = " ".join([*COMMAND, "--out", "runs/demo", *extra])
        record = record_run(run, args.out.stem, f"make run  (fixer4d {shown})" if not extra else f"fixer4d {shown}")
    reference = json.loads(args.against.read_text())
    rows = compare(record["rows"], reference["rows"])
    record["compared_with"] = {"file": str(args.against.relative_to(ROOT) if args.against.is_absolute()
                                           and ROOT in args.against.parents else args.against),
                               "commit": reference.get("commit"), "rows": rows,
                               "every_row_psnr_identical": all(r["identical"] for r in rows.values())}
    write_json(args.out, record)
    print(f"every row identical: {record['compared_with']['every_row_psnr_identical']}; "
          f"stages {sum(record['stage_seconds'].values()):.0f} s -> {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
