"""`fixer4d bench NAME [options]`: run one benchmark (or `all`), print and save its numbers.

Each benchmark is a module here with ``main(argv) -> int`` that writes a JSON file; README
tables are made from those files.
"""
from __future__ import annotations

import argparse
import importlib

BENCHES: dict[str, str] = {
    "raycast": "fixer4d.bench.raycast",
    "raster": "fixer4d.bench.raster",
    "train-step": "fixer4d.bench.train_step",
    "at": "fixer4d.bench.at_cost",
    "iteration": "fixer4d.bench.iteration",
    "restore": "fixer4d.bench.restore",
    "viewer": "app.bench",
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("name", choices=sorted(BENCHES) + ["all"], help="which benchmark")
    parser.add_argument("rest", nargs=argparse.REMAINDER, help="options passed to the benchmark (see NAME --help)")


def run(args: argparse.Namespace) -> int:
    names = sorted(BENCHES) if args.name == "all" else [args.name]
    if args.name == "all" and {"-h", "--help"} & set(args.rest):
        print("fixer4d bench all [--out DIR]: runs " + ", ".join(names) + " one after the other, each writing "
              "DIR/<name>.json (see `fixer4d bench NAME --help` for each one's options)")
        return 0
    status = 0
    for name in names:
        rest = list(args.rest)
        if args.name == "all" and "--out" in rest:
            i = rest.index("--out")
            # the file each benchmark writes by default (train-step -> train_step.json)
            rest[i + 1] = f"{rest[i + 1].rstrip('/')}/{name.replace('-', '_')}.json"
        status |= int(importlib.import_module(BENCHES[name]).main(rest) or 0)
    return status
