"""numba vs C++ on the forward compositing loop of fixer4d's CPU rasterizer (decision record).

    PYTHONPATH=. .venv/bin/python benchmarks/probe_cpp/run.py [--n 50000] [--size 320x240] [--repeats 7]

Builds the `fixer4d bench raster` scene (N random-init Gaussians, opacity 0.1, 3-NN scales),
projects and bins it with fixer4d/render/cpu.py, then times the forward compositing alone on
that same binned input: the numba kernel (cpu._forward) and forward.cpp compiled here with
g++ -O3 -march=native -ffp-contract=off -fopenmp into a temporary directory (nothing is written to the tree).
Both use every core with the same static tile split. Reports wall and process-CPU ns per
blended fragment (best of --repeats), the outputs' agreement and the load average.

Since the kernel evaluates the conic in LDL form (project.stable_conic) and skips rows per
splat, while forward.cpp keeps the textbook (a, b, c) form over the splat's box rows, the two
agree to float32 round-off (~1e-6), no longer bit for bit; the table in docs/render.md was
measured before that change.
"""
from __future__ import annotations

import argparse
import ctypes
import math
import os
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent


def build(tmp: Path) -> ctypes.CDLL:
    lib = tmp / "forward.so"
    # -ffp-contract=off: no fused multiply-add, so every float32 operation rounds as in numba
    # (GCC contracts a*b+c by default once -march enables FMA); PROBE_CXXFLAGS adds flags
    cmd = ["g++", "-O3", "-march=native", "-ffp-contract=off", "-fopenmp", "-shared", "-fPIC", "-std=c++17",
           *os.environ.get("PROBE_CXXFLAGS", "").split(), str(HERE / "forward.cpp"), "-o", str(lib)]
    subprocess.run(cmd, check=True)
    return ctypes.CDLL(str(lib))


def ptr(a: np.ndarray):
    return a.ctypes.data_as(ctypes.c_void_p)


def best(fn, repeats: int) -> tuple[float, float]:
    fn()  # warm-up (JIT cache, first-touch of the outputs)
    wall, cpu = [], []
    for _ in range(repeats):
        c0, t0 = time.process_time(), time.perf_counter()
        fn()
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return min(wall), min(cpu)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=50_000)
    ap.add_argument("--size", default="320x240")
    ap.add_argument("--repeats", type=int, default=7)
    args = ap.parse_args()
    width, height = (int(v) for v in args.size.split("x"))

    import numba
    import torch

    from fixer4d.bench.raster import random_init_snapshot
    from fixer4d.geometry.camera import Camera
    from fixer4d.render import cpu
    from fixer4d.render.project import project_gaussians

    torch.set_num_threads(1)
    snap = random_init_snapshot(args.n, (-1, -1, -1), (1, 1, 1))
    cam = Camera.look_at([0.0, 0.0, -4.0], [0.0, 0.0, 0.0], fov_y=math.radians(50.0), width=width, height=height)
    with torch.no_grad():
        proj = project_gaussians(snap, cam)
    f = cpu._as_np
    mx, my = f(proj.means2d[:, 0]), f(proj.means2d[:, 1])
    ca, cb, cc = f(proj.conics[:, 0]), f(proj.conics[:, 1]), f(proj.conics[:, 2])
    op, col, z = f(proj.opacities), f(proj.colors), f(proj.depths)
    radii = proj.radii.numpy().astype(np.int64)
    visible = np.nonzero((radii > 0) & (op >= cpu._ALPHA_MIN))[0]
    order = visible[np.argsort(z[visible], kind="stable")].astype(np.int64)
    rec = cpu._records(proj.means2d, proj.conic_ldl, proj.opacities, proj.colors, proj.depths)
    offsets, ids = cpu._bin_tiles(rec, radii, order, width, height, cpu._TILE)
    rows = rec[:, [cpu._R_ROW0, cpu._R_ROW1]].astype(np.int64)
    n_threads = numba.get_num_threads()
    _, dealt = cpu._tile_orders(offsets, n_threads)
    n_tiles = offsets.shape[0] - 1

    def outputs():
        return (np.empty((height, width, 3), np.float32), np.empty((height, width), np.float32),
                np.empty((height, width), np.float32), np.empty((height, width), np.int32))

    nb = outputs()
    frags = int(cpu._forward(rec, offsets, ids, dealt, width, height, *nb).sum())
    torch.set_num_threads(1)  # numba's first parallel launch raises it (shared libgomp)
    results = {"numba lanes": best(lambda: cpu._forward(rec, offsets, ids, dealt, width, height, *nb), args.repeats)}
    with tempfile.TemporaryDirectory() as tmp:
        lib = build(Path(tmp))
        lib.forward_lanes.restype = ctypes.c_int64
        lib.forward_pixel.restype = ctypes.c_int64
        rows32 = np.ascontiguousarray(rows.astype(np.int32))
        cl, cp = outputs(), outputs()
        common = [ptr(a) for a in (mx, my, ca, cb, cc, op, col, z, offsets, ids)]

        def lanes():
            return lib.forward_lanes(*common, ptr(rows32), ptr(dealt), ctypes.c_int64(n_tiles), width, height,
                                     n_threads, *(ptr(a) for a in cl))

        def pixel():
            return lib.forward_pixel(*common, ptr(dealt), ctypes.c_int64(n_tiles), width, height, n_threads,
                                     *(ptr(a) for a in cp))

        frags_lanes, frags_pixel = int(lanes()), int(pixel())
        results["C++ lanes"] = best(lanes, args.repeats)
        results["C++ pixel walk (expf)"] = best(pixel, args.repeats)
    load = os.getloadavg()
    print(f"N={args.n} {width}x{height}: {frags} fragments ({frags / (width * height):.1f}/px), "
          f"{n_threads} threads, load average {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}")
    for name, (wall, cpu_s) in results.items():
        print(f"  {name:22s} wall {wall * 1e3:7.1f} ms  {wall * 1e9 / frags:6.2f} ns/frag   "
              f"cpu {cpu_s * 1e3:7.1f} ms  {cpu_s * 1e9 / frags:6.2f} ns/frag")
    for name, out, fr in (("C++ lanes", cl, frags_lanes), ("C++ pixel", cp, frags_pixel)):
        diff = max(float(np.abs(a.astype(np.float64) - b).max()) for a, b in zip(out[:3], nb[:3]))
        print(f"  {name} vs numba: fragments {fr} vs {frags}, max |diff| {diff:.2e}, "
              f"bit-identical rgb {np.array_equal(out[0], nb[0])}")


if __name__ == "__main__":
    main()
