"""Whole training iterations with an older CPU renderer vs the current one, as ratios in one process.

    PYTHONPATH=. .venv/bin/python benchmarks/probe_kernel/compare.py [--old 81f3ca1 [--old 87816b2]]
        [--sizes 0.5,1.0] [--counts 30000,100000] [--iters 8] [--out FILE.json]

The `fixer4d bench train-step` scene (Panoptic basketball frame 0, N random points in the
cameras' common view box, 3-NN scales, opacity 0.1, one image per iteration: render +
stg_loss + backward + Adam). For each --old git revision, that revision's
fixer4d/render/cpu.py is loaded from git into a temporary module and paired with the torch
projection (project.project_gaussians, what every earlier release used); "new" is the current
render() path (numba projection + current kernels). Every variant trains its own copy of the
same model, and the variants take turns iteration by iteration, so a change in the machine's
load hits them alike: on the shared 2-core machine only these ratios are meaningful, never
the absolute seconds. All variants run with the same numba vector width (numba's CPU features
are set once per process: see fixer4d/simd.py). Reports per variant median wall and
process-CPU seconds per iteration, blended fragments, ns/fragment of wall, the ratios old/new
and the load average.
"""
from __future__ import annotations

import argparse
import importlib.util
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[2]


def load_old_kernel(rev: str, tmp: Path):
    """The module fixer4d/render/cpu.py of git revision ``rev``, importable beside the current one."""
    src = subprocess.run(["git", "show", f"{rev}:fixer4d/render/cpu.py"], cwd=ROOT, check=True,
                         capture_output=True, text=True).stdout
    path = tmp / f"cpu_{rev}.py"
    path.write_text(src)
    spec = importlib.util.spec_from_file_location(f"cpu_{rev}", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def render_old(kernel, snapshot, camera):
    """render() as the old releases did it: torch projection, then ``kernel``'s rasterizer
    (fed the (a, b, c) conic when it predates the LDL form). Background black."""
    from fixer4d.render.project import project_gaussians

    snapshot = snapshot.to(dtype=torch.float32)
    proj = project_gaussians(snapshot, camera)
    color, trans, _depth, n_frag = kernel.rasterize_cpu(proj, camera.width, camera.height)
    return color, n_frag


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--old", action="append", default=None, help="git revision(s) of the old kernel")
    p.add_argument("--sizes", default="1.0", help="image scales of 640x360, comma-separated")
    p.add_argument("--counts", default="30000,100000")
    p.add_argument("--iters", type=int, default=8, help="timed iterations per variant (after 2 warm-ups)")
    p.add_argument("--out", default=None, help="JSON file for the rows")
    args = p.parse_args(argv)
    olds = args.old or ["81f3ca1"]
    torch.set_num_threads(1)
    # before any kernel module (old ones included) makes numba build its CPU target: every
    # variant gets the library's vector width (16 lanes on AVX-512 unless FIXER4D_NUMBA_AVX512=0)
    from fixer4d.simd import prefer_512_bit_vectors

    print("numba CPU features set:", "host, -prefer-256-bit" if prefer_512_bit_vectors() else "default")

    from fixer4d.bench.train_step import DEFAULT_DATA, LRS, common_view_box
    from fixer4d.model.spacetime import ModelConfig, SpacetimeGaussians
    from fixer4d.render.api import render
    from fixer4d.scene import load_scene
    from fixer4d.train.losses import stg_loss

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        kernels = {rev: load_old_kernel(rev, Path(tmp)) for rev in olds}
        for scale in (float(s) for s in args.sizes.split(",")):
            scene = load_scene(DEFAULT_DATA, scale=scale)
            cams = list(scene.cameras)
            targets = [torch.from_numpy(np.ascontiguousarray(scene.frame(0, i))) for i in range(len(cams))]
            lo, hi = common_view_box(cams)
            for n in (int(c) for c in args.counts.split(",")):
                rng = np.random.default_rng(0)
                pts, cols = rng.uniform(lo, hi, (n, 3)), rng.uniform(0, 1, (n, 3))
                variants = {}
                for name in [*olds, "new"]:
                    model = SpacetimeGaussians.from_points(pts, cols, np.zeros(n), ModelConfig(), opacity=0.1)
                    opt = torch.optim.Adam(model.param_groups(LRS), eps=1e-15)
                    if name == "new":
                        fn = lambda s, c: (lambda o: (o.rgb, o.n_fragments))(render(s, c, background=(0, 0, 0), backend="cpu"))  # noqa: E731
                    else:
                        fn = lambda s, c, k=kernels[name]: render_old(k, s, c)  # noqa: E731
                    variants[name] = (model, opt, fn, {"wall": [], "cpu": [], "frags": []})
                load0 = os.getloadavg()[0]
                for it in range(args.iters + 2):
                    i = it % len(cams)
                    for name, (model, opt, fn, rec) in variants.items():
                        c0, t0 = time.process_time(), time.perf_counter()
                        rgb, n_frag = fn(model.at(0.0), cams[i])
                        loss = stg_loss(rgb, targets[i])
                        opt.zero_grad(set_to_none=True)
                        loss.backward()
                        opt.step()
                        if it >= 2:
                            rec["wall"].append(time.perf_counter() - t0)
                            rec["cpu"].append(time.process_time() - c0)
                            rec["frags"].append(n_frag)
                row = {"n_gaussians": n, "width": cams[0].width, "height": cams[0].height,
                       "load_avg": [round(load0, 2), round(os.getloadavg()[0], 2)], "variants": {}}
                for name, (_m, _o, _f, rec) in variants.items():
                    wall, cpu = float(np.median(rec["wall"])), float(np.median(rec["cpu"]))
                    fr = float(np.mean(rec["frags"]))
                    row["variants"][name] = {"s_per_iter": round(wall, 4), "cpu_s_per_iter": round(cpu, 4),
                                             "fragments": fr, "ns_per_fragment_wall": round(wall * 1e9 / fr, 2)}
                new = row["variants"]["new"]
                for rev in olds:
                    v = row["variants"][rev]
                    v["ratio_wall_vs_new"] = round(v["s_per_iter"] / new["s_per_iter"], 2)
                    v["ratio_cpu_vs_new"] = round(v["cpu_s_per_iter"] / new["cpu_s_per_iter"], 2)
                rows.append(row)
                print(json.dumps(row), flush=True)
    if args.out:
        Path(args.out).write_text(json.dumps({"rows": rows, "iters": args.iters}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
