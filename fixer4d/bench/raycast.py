"""`fixer4d bench raycast`: ms per ray-cast frame of the ground-truth renderer.

Renders a spec (default: the demo scene) from its first camera re-made at each resolution
(same pose and vertical field of view), at supersampling 1 and 2, best (and median) wall time
of several frames at different times, plus the best process CPU time (single-threaded numpy, so
on a loaded machine CPU time is the figure closest to an idle machine's wall time). Rows go to
JSON (default benchmarks/results/raycast.json).
"""
from __future__ import annotations

import argparse
import os
import platform
import time

import numpy as np

DEFAULT_OUT = "benchmarks/results/raycast.json"
DEFAULT_SIZES = ("200x150", "320x240", "640x360")  # the demo resolution + the two reference sizes
DEFAULT_SUPERSAMPLE = (1, 2)
# Untimed frames first: the first call pays imports and allocator growth.
WARMUP_FRAMES = 1


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(x) for x in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"size {text!r}: expected WxH, e.g. 320x240") from None
    if w <= 0 or h <= 0:
        raise argparse.ArgumentTypeError(f"size {text!r}: width and height must be positive")
    return w, h


def measure(spec: str, sizes: list[tuple[int, int]], supersample: list[int], repeats: int) -> list[dict]:
    """One row per (size, supersample): best and median ms per frame, rays per second."""
    from fixer4d.geometry.camera import Camera
    from fixer4d.scene import raycast
    from fixer4d.scene.synthetic import SyntheticScene

    scene = SyntheticScene(spec)
    base = scene.cameras[0]
    rows = []
    for w, h in sizes:
        cam = Camera(Camera.intrinsics_from_fov(base.fov_y, w, h), base.c2w, w, h, base.name)
        for k in supersample:
            for _ in range(WARMUP_FRAMES):
                raycast.render(scene.world, cam, scene.seconds(0.0), supersample=k)
            times, cpu = [], []
            for i in range(repeats):
                t = (i + 0.5) / repeats
                t0, c0 = time.perf_counter(), time.process_time()
                raycast.render(scene.world, cam, scene.seconds(t), supersample=k)
                times.append((time.perf_counter() - t0) * 1e3)
                cpu.append((time.process_time() - c0) * 1e3)
            best = float(np.min(times))
            rows.append({"spec": scene.name, "width": w, "height": h, "supersample": k, "ms": best,
                         "ms_median": float(np.median(times)), "cpu_ms": float(np.min(cpu)),
                         "mrays_per_s": w * h * k * k / best / 1e3,
                         "objects": len(scene.world.objects), "effects": sorted(scene.effects)})
    return rows


def main(argv: list[str] | None = None) -> int:
    from fixer4d.atomic import write_json

    parser = argparse.ArgumentParser(prog="fixer4d bench raycast", description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=DEFAULT_OUT, help=f"JSON output (default {DEFAULT_OUT})")
    parser.add_argument("--spec", default="demo", help="scene spec (name or .json path)")
    parser.add_argument("--sizes", type=_size, nargs="+", default=[_size(s) for s in DEFAULT_SIZES],
                        help="resolutions WxH")
    parser.add_argument("--supersample", type=int, nargs="+", default=list(DEFAULT_SUPERSAMPLE))
    parser.add_argument("--repeats", type=int, default=5, help="timed frames per row (best is reported)")
    args = parser.parse_args(argv)
    rows = measure(args.spec, args.sizes, args.supersample, max(1, args.repeats))
    print(f"{'size':>9} {'ss':>3} {'ms/frame':>9} {'median':>8} {'cpu ms':>7} {'Mray/s':>7}")
    for r in rows:
        print(f"{r['width']:>4}x{r['height']:<4} {r['supersample']:>3} {r['ms']:>9.1f} {r['ms_median']:>8.1f} "
              f"{r['cpu_ms']:>7.1f} {r['mrays_per_s']:>7.2f}")
    write_json(args.out, {"benchmark": "raycast", "rows": rows, "repeats": args.repeats,
                          "machine": {"platform": platform.platform(), "cpus": os.cpu_count(),
                                      "processor": platform.processor()}})
    print(f"wrote {args.out}")
    return 0
