"""`fixer4d bench raster`: forward and forward+backward time and peak memory of the CPU
rasterizers (oracle vs numba kernel) for N in {10k, 50k, 200k} at 320x240 and 640x360.

Scene: N Gaussians uniform in the cube [-1, 1]^3 seen from 4 units away (50 degree vertical
fov), opacity 0.1 and isotropic scales from the mean 3-nearest-neighbour distance, the way a
random initialisation starts (OpenSplat, 3DGS). Output contract (issue 3):
{"rows": [{"backend", "n_gaussians", "width", "height", "pass", "ms", "peak_mb",
"fragments_per_pixel", "ns_per_fragment"}], "skipped": [...], "scaling": {...}, "machine": {...}}.
"""
from __future__ import annotations

import argparse
import math
import os
import platform
import threading
import time
from pathlib import Path

import numpy as np

DEFAULT_OUT = Path("benchmarks/results/raster.json")
SIZES = ((320, 240), (640, 360))
COUNTS = (10_000, 50_000, 200_000)
# the oracle's per-tile dense tensors make it minutes-slow beyond this; rows above are skipped
REFERENCE_MAX_N = 50_000
INIT_OPACITY = 0.1  # random-init opacity of 3DGS/OpenSplat
RSS_POLL_S = 0.002  # peak-memory sampler period


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


class PeakRSS:
    """Peak resident memory above the level at entry, sampled by a thread (MiB)."""

    def __enter__(self):
        self.base = self._rss()
        self.peak = self.base
        self._stop = threading.Event()
        self._t = threading.Thread(target=self._poll, daemon=True)
        self._t.start()
        return self

    def _poll(self):
        while not self._stop.is_set():
            self.peak = max(self.peak, self._rss())
            time.sleep(RSS_POLL_S)

    def __exit__(self, *exc):
        self._stop.set()
        self._t.join()
        self.peak = max(self.peak, self._rss())

    @property
    def mb(self) -> float:
        return (self.peak - self.base) / 2 ** 20

    @staticmethod
    def _rss() -> int:
        with open("/proc/self/statm") as fh:
            return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE")


def machine_info() -> dict:
    import numba
    import torch

    model = ""
    try:
        for line in open("/proc/cpuinfo"):
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return {"cpu": model or platform.processor(), "cores": os.cpu_count(), "numba_threads": numba.get_num_threads(),
            "torch_threads": torch.get_num_threads(), "python": platform.python_version(),
            "torch": torch.__version__, "numba": numba.__version__, "platform": platform.platform()}


def time_pass(snap, cam, backend: str, with_backward: bool, repeats: int) -> tuple[float, float, int]:
    """(median ms, peak MiB, fragments) of render (+ backward of a fixed random loss)."""
    import torch

    from fixer4d.render.api import render

    g = torch.Generator().manual_seed(0)
    w = torch.rand(cam.height, cam.width, 3, generator=g)

    def once():
        if with_backward:
            leaves = [t.detach().requires_grad_(True) for t in (snap.means, snap.quats, snap.scales,
                                                                snap.opacities, snap.colors)]
            from fixer4d.model.snapshot import Snapshot

            out = render(Snapshot(*leaves), cam, backend=backend)
            ((out.rgb * w).sum() + out.depth.mean()).backward()
        else:
            with torch.no_grad():
                out = render(snap, cam, backend=backend)
        return out.n_fragments

    warm = snap.subset(torch.arange(min(len(snap), 100)))
    with torch.no_grad():  # warm-up on a tiny subset: loads the JIT cache, not counted in memory
        render(warm, cam, backend=backend)
    times = []
    with PeakRSS() as mem:
        for _ in range(repeats):
            t0 = time.perf_counter()
            frags = once()
            times.append((time.perf_counter() - t0) * 1e3)
    return float(np.median(times)), mem.mb, frags


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

    import torch
    from tqdm import tqdm

    from fixer4d.atomic import write_json
    from fixer4d.geometry.camera import Camera

    torch.set_num_threads(args.torch_threads)
    counts = (50_000,) if args.quick else COUNTS
    sizes = ((320, 240),) if args.quick else SIZES
    rows, skipped = [], []
    jobs = [(n, s, b, p) for n in counts for s in sizes for b in ("cpu", "reference") for p in ("fwd", "fwd+bwd")]
    snaps = {}
    for n, (w, h), backend, p in tqdm(jobs, desc="bench raster"):
        if backend == "reference" and n > REFERENCE_MAX_N:
            skipped.append({"backend": backend, "n_gaussians": n, "width": w, "height": h, "pass": p,
                            "reason": f"oracle not run above {REFERENCE_MAX_N} Gaussians (too slow)"})
            continue
        if n not in snaps:
            snaps[n] = random_init_snapshot(n, (-1, -1, -1), (1, 1, 1))
        cam = Camera.look_at([0.0, 0.0, -4.0], [0.0, 0.0, 0.0], fov_y=math.radians(50.0), width=w, height=h)
        ms, mb, frags = time_pass(snaps[n], cam, backend, p == "fwd+bwd", args.repeats if backend == "cpu" else 1)
        rows.append({"backend": backend, "n_gaussians": n, "width": w, "height": h, "pass": p,
                     "ms": round(ms, 2), "peak_mb": round(mb, 1),
                     "fragments_per_pixel": round(frags / (w * h), 2),
                     "ns_per_fragment": round(ms * 1e6 / max(frags, 1), 2)})
    speedups = {}
    for r in rows:
        if r["backend"] == "cpu":
            ref = [q for q in rows if q["backend"] == "reference" and
                   all(q[k] == r[k] for k in ("n_gaussians", "width", "height", "pass"))]
            if ref:
                speedups[f"{r['n_gaussians']} {r['width']}x{r['height']} {r['pass']}"] = round(ref[0]["ms"] / r["ms"], 1)
    result = {"rows": rows, "skipped": skipped, "speedup_cpu_over_reference": speedups,
              "scaling": scaling(rows), "machine": machine_info(), "torch_threads": args.torch_threads,
              "scene": "uniform cube [-1,1]^3, camera at distance 4, fov 50 deg, opacity 0.1, 3-NN scales"}
    write_json(args.out, result)
    print(f"{'backend':10s} {'N':>7s} {'size':>8s} {'pass':>8s} {'ms':>10s} {'peak MB':>8s} {'frag/px':>8s} {'ns/frag':>8s}")
    for r in rows:
        print(f"{r['backend']:10s} {r['n_gaussians']:7d} {r['width']}x{r['height']:<4d} {r['pass']:>8s} {r['ms']:10.1f} "
              f"{r['peak_mb']:8.1f} {r['fragments_per_pixel']:8.1f} {r['ns_per_fragment']:8.2f}")
    for k, v in speedups.items():
        print(f"speed-up cpu/reference {k}: {v}x")
    for k, v in result["scaling"].items():
        print(f"{k}: {v}")
    print(f"wrote {args.out}")
    return 0
