"""`fixer4d bench NAME [options]`: run one benchmark (or `all`), print and save its numbers.

Each benchmark is a module here with ``main(argv) -> int`` that writes a JSON file; README
tables are made from those files. Packages that sit above the library add their own benchmarks
through the ``fixer4d.benches`` entry-point group (the desktop viewer registers ``viewer``
there), so the library never names them.
"""
from __future__ import annotations

import argparse
import importlib
from importlib.metadata import entry_points
from typing import Callable

# Entry-point group other packages register benchmarks in: name = "module:main".
ENTRY_POINT_GROUP = "fixer4d.benches"

BENCHES: dict[str, str] = {
    "raycast": "fixer4d.bench.raycast",
    "raster": "fixer4d.bench.raster",
    "train-step": "fixer4d.bench.train_step",
    "at": "fixer4d.bench.at_cost",
    "iteration": "fixer4d.bench.iteration",
    "restore": "fixer4d.bench.restore",
    "quality": "fixer4d.bench.quality",
}
# Studies of hours (whole runs over seeds and camera sets): run by name only, never by `all`.
LONG_STUDIES = ("quality",)


def registered() -> dict[str, Callable[[list[str]], int]]:
    """Every benchmark: name -> a loader of its ``main`` (the library's own, then the ones
    installed packages register under ENTRY_POINT_GROUP)."""
    out: dict[str, Callable] = {name: (lambda m=module: importlib.import_module(m).main) for name, module in BENCHES.items()}
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        out.setdefault(ep.name, ep.load)
    return out


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("name", choices=sorted(registered()) + ["all"], help="which benchmark")
    parser.add_argument("rest", nargs=argparse.REMAINDER, help="options passed to the benchmark (see NAME --help)")


def run(args: argparse.Namespace) -> int:
    benches = registered()
    names = sorted(set(benches) - set(LONG_STUDIES)) if args.name == "all" else [args.name]
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
        status |= int(benches[name]()(rest) or 0)
    return status
