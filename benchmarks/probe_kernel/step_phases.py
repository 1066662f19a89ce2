"""Wall milliseconds of each phase of one training iteration on the `fixer4d bench train-step` scene.

    .venv/bin/python benchmarks/probe_kernel/step_phases.py [--count 100000] [--scale 1.0] [--iters 10]

Panoptic basketball frame 0, N random points in the cameras' common view box (as the bench),
one image per iteration, torch on one thread, numba on every core. Phases: model.at(t), render
(projection + records + sort + binning + forward kernel), loss (with the fused CPU loss this
includes its gradient), backward (backward kernel + projection backward), Adam step. Medians
over --iters iterations after 2 warm-ups, plus wall and process-CPU per iteration and wall ns
per blended fragment. FIXER4D_FUSED_LOSS=0 runs the torch loss for comparison. The figures in
docs/render.md at commit 9fd7044 ("Kernel v5") came from this script on the idle machine.
"""
from __future__ import annotations

import argparse
import time

import numpy as np
import torch


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--count", type=int, default=100_000)
    parser.add_argument("--scale", type=float, default=1.0, help="of 640x360")
    parser.add_argument("--iters", type=int, default=10)
    args = parser.parse_args()

    from fixer4d.bench.train_step import DEFAULT_DATA, LRS, common_view_box
    from fixer4d.model.densify import make_adam
    from fixer4d.model.spacetime import ModelConfig, SpacetimeGaussians
    from fixer4d.render.api import render
    from fixer4d.scene import load_scene
    from fixer4d.train.losses import stg_loss
    from fixer4d.train.trainer import ADAM_EPS

    torch.set_num_threads(1)
    scene = load_scene(DEFAULT_DATA, scale=args.scale)
    cams = list(scene.cameras)
    lo, hi = common_view_box(cams)
    rng = np.random.default_rng(0)
    pts, cols = rng.uniform(lo, hi, (args.count, 3)), rng.uniform(0, 1, (args.count, 3))
    targets = [torch.from_numpy(np.ascontiguousarray(scene.frame(0, i))) for i in range(len(cams))]
    model = SpacetimeGaussians.from_points(pts, cols, np.zeros(args.count), ModelConfig(), opacity=0.1)
    opt = make_adam(model.param_groups(LRS), eps=ADAM_EPS)

    def step(i: int) -> tuple[list[float], int]:
        ts = [time.perf_counter()]
        snap = model.at(0.0)
        ts.append(time.perf_counter())
        out = render(snap, cams[i % len(cams)], backend="cpu")
        ts.append(time.perf_counter())
        loss = stg_loss(out.rgb, targets[i % len(cams)])
        ts.append(time.perf_counter())
        opt.zero_grad(set_to_none=True)
        loss.backward()
        ts.append(time.perf_counter())
        opt.step()
        ts.append(time.perf_counter())
        return list(np.diff(ts)), int(out.n_fragments)

    for i in range(2):
        step(i)
    rows, frags = [], []
    for i in range(args.iters):
        c0 = time.process_time()
        t0 = time.perf_counter()
        parts, fr = step(i)
        rows.append(parts + [time.perf_counter() - t0, time.process_time() - c0])
        frags.append(fr)
    med = np.median(np.array(rows), 0) * 1000.0
    names = ("at", "render", "loss", "backward", "adam", "total wall", "total cpu")
    print("  ".join(f"{n} {v:.1f}" for n, v in zip(names, med)), "ms;",
          f"{med[5] * 1e6 / np.mean(frags):.2f} ns per fragment (wall)")


if __name__ == "__main__":
    main()
