"""`fixer4d bench raster`: forward and forward+backward time and peak memory of the CPU
rasterizers (oracle vs numba kernel) for N in {10k, 50k, 200k} at 320x240 and 640x360.

Scene: N Gaussians uniform in the cube [-1, 1]^3 seen from 4 units away (50 degree vertical
fov), opacity 0.1 and isotropic scales from the mean 3-nearest-neighbour distance, the way a
random initialisation starts (OpenSplat, 3DGS). Output contract:
{"rows": [{"backend", "n_gaussians", "width", "height", "pass", "ms", "peak_mb",
"fragments_per_pixel", "ns_per_fragment", "base_mb", "load_avg"}], "skipped": [...], "scaling": {...},
"machine": {...}}.

Every row runs in a fresh Python process, so that its memory and timing are its own: peak_mb is
that process's peak resident set (getrusage ru_maxrss: Python + torch + numba + the scene + the
renders, everything the kernels and torch allocate included), base_mb its resident set just
before the timed passes (after imports, the scene and a JIT warm-up); peak_mb - base_mb is what
the timed renders added at their high-water mark. load_avg is the 1-minute load average at the
end of the row (other processes share the 2 cores: compare rows only at similar load).
"""
from __future__ import annotations

import argparse
import json
import math
import os
import resource
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

DEFAULT_OUT = Path("benchmarks/results/raster.json")
SIZES = ((320, 240), (640, 360))
COUNTS = (10_000, 50_000, 200_000)
# the oracle's per-tile dense tensors make it minutes-slow beyond this; rows above are skipped
REFERENCE_MAX_N = 50_000
INIT_OPACITY = 0.1  # random-init opacity of 3DGS/OpenSplat


def knn_scale(points: np.ndarray, k: int = 3) -> np.ndarray:
    """(N,) mean distance to the k nearest neighbours (the 3DGS initial scale)."""
    from scipy.spatial import cKDTree

    d, _ = cKDTree(points).query(points, k=k + 1)
    return np.maximum(d[:, 1:].mean(1), 1e-7)


def random_init_snapshot(n: int, bbox_min, bbox_max, seed: int = 0):
    """N random-init Gaussians uniform in a box: random colours, opacity 0.1, 3-NN scales."""
    import torch

    from fixer4d.model.snapshot import Snapshot

    rng = np.random.default_rng(seed)
    lo, hi = np.asarray(bbox_min, np.float64), np.asarray(bbox_max, np.float64)
    pts = rng.uniform(lo, hi, (n, 3))
    scales = np.repeat(knn_scale(pts)[:, None], 3, 1)
    f = lambda a: torch.tensor(a, dtype=torch.float32)  # noqa: E731
    quats = np.zeros((n, 4))
    quats[:, 0] = 1.0
    return Snapshot(f(pts), f(quats), f(scales), f(np.full(n, INIT_OPACITY)), f(rng.uniform(0, 1, (n, 3))))


def _rss_mb() -> float:
    with open("/proc/self/statm") as fh:
        return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2 ** 20


def time_pass(snap, cam, backend: str, with_backward: bool, repeats: int) -> tuple[float, int, float]:
    """(median ms, fragments, RSS MiB before the timed passes) of render (+ backward of a fixed
    random loss). Meant to run in a fresh process (see run_row) so ru_maxrss is the row's peak."""
    import torch

    from fixer4d.model.snapshot import Snapshot
    from fixer4d.render.api import render

    g = torch.Generator().manual_seed(0)
    w = torch.rand(cam.height, cam.width, 3, generator=g)

    def once():
        if with_backward:
            leaves = [t.detach().requires_grad_(True) for t in (snap.means, snap.quats, snap.scales,
                                                                snap.opacities, snap.colors)]
            out = render(Snapshot(*leaves), cam, backend=backend)
            ((out.rgb * w).sum() + out.depth.mean()).backward()
        else:
            with torch.no_grad():
                out = render(snap, cam, backend=backend)
        return out.n_fragments

    warm = snap.subset(torch.arange(min(len(snap), 100)))
    with torch.no_grad():  # warm-up on a tiny subset: loads the JIT cache
        render(warm, cam, backend=backend)
    base = _rss_mb()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        frags = once()
        times.append((time.perf_counter() - t0) * 1e3)
    return float(np.median(times)), frags, base


def bench_camera(w: int, h: int):
    from fixer4d.geometry.camera import Camera

    return Camera.look_at([0.0, 0.0, -4.0], [0.0, 0.0, 0.0], fov_y=math.radians(50.0), width=w, height=h)


def _row_child(spec: str) -> None:
    """Entry point of a row's fresh process: prints the row as JSON on the last stdout line."""
    import torch

    a = json.loads(spec)
    torch.set_num_threads(a["torch_threads"])
    snap = random_init_snapshot(a["n"], (-1, -1, -1), (1, 1, 1))
    cam = bench_camera(a["w"], a["h"])
    ms, frags, base = time_pass(snap, cam, a["backend"], a["pass"] == "fwd+bwd", a["repeats"])
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # KiB on Linux
    print(json.dumps({"ms": ms, "frags": frags, "base_mb": base, "peak_mb": peak,
                      "load_avg": os.getloadavg()[0]}))


def run_row(n: int, w: int, h: int, backend: str, pass_: str, repeats: int, torch_threads: int) -> dict:
    """Run one row in a fresh interpreter (so ru_maxrss is that row's own peak)."""
    spec = json.dumps({"n": n, "w": w, "h": h, "backend": backend, "pass": pass_, "repeats": repeats,
                       "torch_threads": torch_threads})
    code = f"from fixer4d.bench.raster import _row_child; _row_child({spec!r})"
    env = dict(os.environ)
    root = str(Path(__file__).resolve().parents[2])
    env["PYTHONPATH"] = root + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env)
    if res.returncode != 0:
        raise RuntimeError(f"bench raster row {backend} N={n} {w}x{h} {pass_} failed:\n{res.stderr[-2000:]}")
    return json.loads(res.stdout.strip().splitlines()[-1])


def _exponent(xs, ys) -> float | None:
    if len(xs) < 2:
        return None
    return float(np.polyfit(np.log(xs), np.log(ys), 1)[0])


def scaling(rows: list[dict]) -> dict:
    """Log-log slopes of ms against N (per size) and against pixels (per N)."""
    out: dict = {}
    for backend in sorted({r["backend"] for r in rows}):
        for p in ("fwd", "fwd+bwd"):
            sel = [r for r in rows if r["backend"] == backend and r["pass"] == p]
            for (w, h) in sorted({(r["width"], r["height"]) for r in sel}):
                s = sorted((r["n_gaussians"], r["ms"]) for r in sel if (r["width"], r["height"]) == (w, h))
                e = _exponent([a for a, _ in s], [b for _, b in s])
                if e is not None:
                    out[f"{backend} {p} ms ~ N^k at {w}x{h}"] = round(e, 3)
            for n in sorted({r["n_gaussians"] for r in sel}):
                s = sorted((r["width"] * r["height"], r["ms"]) for r in sel if r["n_gaussians"] == n)
                e = _exponent([a for a, _ in s], [b for _, b in s])
                if e is not None:
                    out[f"{backend} {p} ms ~ pixels^k at N={n}"] = round(e, 3)
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="fixer4d bench raster", description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help="JSON output file")
    parser.add_argument("--quick", action="store_true", help="only the 50k, 320x240 rows")
    parser.add_argument("--repeats", type=int, default=3, help="timed repeats of the fast kernel (median)")
    parser.add_argument("--torch-threads", type=int, default=1,
                        help="torch intra-op threads for the projection (the numba kernels use every core)")
    args = parser.parse_args(argv)

    from tqdm import tqdm

    from fixer4d.atomic import write_json

    counts = (50_000,) if args.quick else COUNTS
    sizes = ((320, 240),) if args.quick else SIZES
    rows, skipped = [], []
    jobs = [(n, s, b, p) for n in counts for s in sizes for b in ("cpu", "reference") for p in ("fwd", "fwd+bwd")]
    for n, (w, h), backend, p in tqdm(jobs, desc="bench raster"):
        if backend == "reference" and n > REFERENCE_MAX_N:
            skipped.append({"backend": backend, "n_gaussians": n, "width": w, "height": h, "pass": p,
                            "reason": f"oracle not run above {REFERENCE_MAX_N} Gaussians (too slow)"})
            continue
        r = run_row(n, w, h, backend, p, args.repeats if backend == "cpu" else 1, args.torch_threads)
        ms, frags = r["ms"], r["frags"]
        rows.append({"backend": backend, "n_gaussians": n, "width": w, "height": h, "pass": p,
                     "ms": round(ms, 2), "peak_mb": round(r["peak_mb"], 1), "base_mb": round(r["base_mb"], 1),
                     "fragments_per_pixel": round(frags / (w * h), 2),
                     "ns_per_fragment": round(ms * 1e6 / max(frags, 1), 2), "load_avg": round(r["load_avg"], 2)})
    speedups = {}
    for r in rows:
        if r["backend"] == "cpu":
            ref = [q for q in rows if q["backend"] == "reference" and
                   all(q[k] == r[k] for k in ("n_gaussians", "width", "height", "pass"))]
            if ref:
                speedups[f"{r['n_gaussians']} {r['width']}x{r['height']} {r['pass']}"] = round(ref[0]["ms"] / r["ms"], 1)
    from fixer4d.bench.machine import machine_info, print_timing_caveats

    result = {"rows": rows, "skipped": skipped, "speedup_cpu_over_reference": speedups,
              "scaling": scaling(rows), "machine": machine_info(reference=True), "torch_threads": args.torch_threads,
              "memory": "peak_mb = ru_maxrss of the row's fresh process; base_mb = its RSS before the timed passes",
              "scene": "uniform cube [-1,1]^3, camera at distance 4, fov 50 deg, opacity 0.1, 3-NN scales"}
    write_json(args.out, result)
    print_timing_caveats(result["machine"])
    print(f"{'backend':10s} {'N':>7s} {'size':>8s} {'pass':>8s} {'ms':>10s} {'peak MB':>8s} {'base MB':>8s} "
          f"{'frag/px':>8s} {'ns/frag':>8s} {'load':>5s}")
    for r in rows:
        print(f"{r['backend']:10s} {r['n_gaussians']:7d} {r['width']}x{r['height']:<4d} {r['pass']:>8s} "
              f"{r['ms']:10.1f} {r['peak_mb']:8.1f} {r['base_mb']:8.1f} {r['fragments_per_pixel']:8.1f} {r['ns_per_fragment']:8.2f} "
              f"{r['load_avg']:5.2f}")
    for k, v in speedups.items():
        print(f"speed-up cpu/reference {k}: {v}x")
    for k, v in result["scaling"].items():
        print(f"{k}: {v}")
    print(f"wrote {args.out}")
    return 0
