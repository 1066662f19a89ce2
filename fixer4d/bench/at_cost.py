"""`fixer4d bench at`: cost of SpacetimeGaussians.at(t) against the share of dynamic Gaussians.

For N Gaussians (default 200k, full STGS-lite config: cubic motion, rotation velocity, temporal
opacity, RGB colour) and dynamic shares 0, 10%, 50%, 100%, it times the forward pass ``at(t)``
and forward + backward (a weighted sum of every Snapshot field, so every Parameter receives a
gradient), best (and median) of several repeats at varying t. A fully static config (no time Parameters at
all) is the floor. Rows go to JSON (default benchmarks/results/at.json).
"""
from __future__ import annotations

import argparse
import os
import platform
import time
from pathlib import Path

from fixer4d.bench import positive_int

DEFAULT_OUT = "benchmarks/results/at.json"
DEFAULT_N = 200_000
SHARES = (0.0, 0.1, 0.5, 1.0)
FIELDS = ("means", "quats", "scales", "opacities", "colors")


def _model(n: int, share: float, static_config: bool, seed: int = 0):
    import torch

    from fixer4d.model.spacetime import ModelConfig, SpacetimeGaussians

    config = ModelConfig(0, False, False, 0) if static_config else ModelConfig()
    g = torch.Generator().manual_seed(seed)
    m = SpacetimeGaussians(config, n)
    with torch.no_grad():
        for name in m.param_names():
            p = getattr(m, name)
            p.copy_(torch.randn(p.shape, generator=g) * 0.3)
    m.set_dynamic(torch.rand(n, generator=g) < share)
    return m


# Untimed calls before timing: the first calls pay allocator growth and page faults.
WARMUP_CALLS = 3


def _time_ms(fn, repeats: int) -> dict[str, float]:
    """Best and median wall time (ms) over ``repeats`` calls at varying t. The best is the
    figure to compare: on a shared machine the median also measures the neighbours' load."""
    import numpy as np

    for _ in range(WARMUP_CALLS):
        fn(0.5)
    times = []
    for i in range(repeats):
        t0 = time.perf_counter()
        fn((i + 0.5) / repeats)
        times.append((time.perf_counter() - t0) * 1e3)
    return {"ms": float(np.min(times)), "ms_median": float(np.median(times))}


def measure(n: int, share: float | None, repeats: int) -> list[dict]:
    """Rows (fwd and fwd+bwd) for one dynamic share; share None = the fully static config."""
    import torch

    m = _model(n, 0.0 if share is None else share, static_config=share is None)
    weights = {f: torch.rand_like(getattr(m.at(0.0), f).detach()) for f in FIELDS}

    def forward(t: float) -> None:
        with torch.no_grad():
            m.at(t)

    def forward_backward(t: float) -> None:
        m.zero_grad(set_to_none=True)
        s = m.at(t)
        sum((getattr(s, f) * weights[f]).sum() for f in FIELDS).backward()

    label = "static config" if share is None else f"{share:.0%}"
    base = {"n_gaussians": n, "dynamic_share": share, "n_dynamic": m.num_dynamic, "config": m.config.to_dict(),
            "label": label}
    return [{**base, "pass": "fwd", **_time_ms(forward, repeats)},
            {**base, "pass": "fwd+bwd", **_time_ms(forward_backward, repeats)}]


def main(argv: list[str] | None = None) -> int:
    import torch

    from fixer4d.atomic import write_json

    parser = argparse.ArgumentParser(prog="fixer4d bench at", description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=DEFAULT_OUT, help=f"JSON output (default {DEFAULT_OUT})")
    parser.add_argument("--n", type=int, default=DEFAULT_N, help=f"number of Gaussians (default {DEFAULT_N})")
    parser.add_argument("--repeats", type=positive_int, default=15, help="timed runs per row (best and median reported)")
    parser.add_argument("--threads", type=int, default=0, help="torch CPU threads (default: torch's choice)")
    args = parser.parse_args(argv)
    if args.threads > 0:
        torch.set_num_threads(args.threads)

    rows: list[dict] = []
    for share in (None, *SHARES):
        rows += measure(args.n, share, args.repeats)
    print(f"at(t) cost, N = {args.n}, torch {torch.__version__}, {torch.get_num_threads()} threads")
    print(f"{'dynamic':>14} {'n_dynamic':>10} {'fwd ms':>9} {'fwd+bwd ms':>11}   (best; median)")
    for fwd, bwd in zip(rows[::2], rows[1::2]):
        print(f"{fwd['label']:>14} {fwd['n_dynamic']:>10} {fwd['ms']:9.2f} {bwd['ms']:11.2f}   "
              f"({fwd['ms_median']:.2f}; {bwd['ms_median']:.2f})")
    machine = {"platform": platform.platform(), "processor": platform.processor(), "cpu_count": os.cpu_count(),
               "torch": torch.__version__, "torch_threads": torch.get_num_threads()}
    out = Path(args.out)
    write_json(out, {"benchmark": "at", "rows": rows, "machine": machine})
    print(f"wrote {out}")
    return 0
