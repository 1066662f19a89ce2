"""How often does MKL's first call ignore the portable pin? Runs one large ``torch.exp`` (MKL's
vector math, called from every OpenMP thread at once) as the first MKL call of a fresh process,
N times with fixer4d's import hook (``numerics._SettleMklOnImport``) and N times with it removed,
with busy processes beside them, and counts the digests of the result.

    python benchmarks/mkl_first_call.py [--runs 25] [--busy 2] [--out benchmarks/results/mkl_first_call.json]

The pinned digest is the most common one with the hook; a run that gives another took MKL's
unpinned code path. The race is rare (about 1 run in 60 under load here): count over many runs.
"""
from __future__ import annotations

import argparse
import collections
import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from fixer4d.atomic import write_json  # noqa: E402
from fixer4d.bench.machine import cpu_topology  # noqa: E402

CHILD = """
import hashlib, sys
import fixer4d
from fixer4d import numerics
if sys.argv[1] == "off":
    sys.meta_path[:] = [f for f in sys.meta_path if not isinstance(f, numerics._SettleMklOnImport)]
import torch
x = torch.randn(100003, generator=torch.Generator().manual_seed(0))
print(hashlib.sha1(torch.exp(x).numpy().tobytes()).hexdigest())
"""


def digests(hook: str, runs: int) -> collections.Counter:
    out = collections.Counter()
    for i in range(runs):
        done = subprocess.run([sys.executable, "-c", CHILD, hook], capture_output=True, text=True, check=True,
                              cwd=ROOT)
        out[done.stdout.strip()] += 1
        print(f"hook {hook}: run {i + 1}/{runs}", file=sys.stderr, end="\r")
    print(file=sys.stderr)
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=25, help="fresh processes per column")
    parser.add_argument("--busy", type=int, default=2, help="busy-looping processes beside them (the load)")
    parser.add_argument("--out", type=Path, default=ROOT / "benchmarks/results/mkl_first_call.json")
    args = parser.parse_args(argv)
    load_before = os.getloadavg()
    busy = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(args.busy)]
    try:
        columns = {hook: digests(hook, args.runs) for hook in ("on", "off")}
    finally:
        for process in busy:
            process.kill()
    pinned = columns["on"].most_common(1)[0][0]
    result = {"command": "python benchmarks/mkl_first_call.py " + " ".join(argv or sys.argv[1:]),
              "machine": cpu_topology(), "busy_processes": args.busy,
              "load_average_1min": {"before": load_before[0], "after": os.getloadavg()[0]},
              "runs": args.runs, "pinned_digest": pinned,
              **{f"hook_{hook}": {"digests": dict(c), "off_the_pin": args.runs - c[pinned]}
                 for hook, c in columns.items()}}
    write_json(args.out, result)
    print(json.dumps({k: result[k] for k in ("hook_on", "hook_off")}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
