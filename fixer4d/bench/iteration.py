"""`fixer4d bench iteration`: seconds per stage-1 training iteration and where they go.

Trains the demo scene (at its own resolution, or --scale) from a dense init made from the
scene's ground-truth depth (so the benchmark does not depend on, or pay for, the MVS stage) and
times each part of an iteration: at(t), render forward, loss, backward, optimizer step and
densification statistics (every step), plus one full densify/prune call. Writes JSON (default
benchmarks/results/iteration.json).
"""
from __future__ import annotations

import argparse
import platform
import time
from pathlib import Path

import numpy as np

# Pixel stride of the depth-based init: every 2nd pixel of every train view of every frame, a
# dense init comparable in size to what the MVS fusion keeps.
INIT_STRIDE = 2
_PARTS = ("t_at", "t_render", "t_loss", "t_backward", "t_optim", "t_densify")


def depth_clouds(scene, stride: int = INIT_STRIDE, frames: list[int] | None = None) -> list:
    """Per-frame clouds back-projected from the scene's ground-truth depth at the train views
    (every ``stride``-th pixel): a stand-in for a perfect dense init. Needs ``scene.has_depth``."""
    from fixer4d.errors import InputError
    from fixer4d.init.cloud import FrameCloud

    if not scene.has_depth:
        raise InputError(f"{scene.name}: no ground-truth depth to build an init from; use a synthetic scene")
    clouds = []
    for f in (range(scene.num_frames) if frames is None else frames):
        pts, cols = [], []
        for c in scene.train_ids:
            depth = np.asarray(scene.depth(f, c), dtype=np.float64)
            ok = np.isfinite(depth) & (depth > 0)
            grid = np.zeros_like(ok)
            grid[stride // 2::stride, stride // 2::stride] = True
            ok &= grid
            xyz = scene.cameras[c].backproject_depth(np.where(ok, depth, 0.0))
            pts.append(xyz[ok])
            cols.append(scene.frame(f, c)[ok])
        clouds.append(FrameCloud(f, scene.time(f), np.concatenate(pts), np.concatenate(cols)))
    return clouds


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="fixer4d bench iteration", description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="demo")
    parser.add_argument("--scale", type=float, default=1.0, help="image scale of the scene")
    parser.add_argument("--iterations", type=int, default=30, help="timed iterations")
    parser.add_argument("--warmup", type=int, default=3, help="untimed iterations first (JIT compilation)")
    parser.add_argument("--backend", default="auto")
    parser.add_argument("--max-points", type=int, default=None, help="init point cap (default: Stage1Config's)")
    parser.add_argument("--out", default="benchmarks/results/iteration.json")
    args = parser.parse_args(argv)

    import torch
    from tqdm import tqdm

    from fixer4d.atomic import write_json
    from fixer4d.model.densify import densify_and_prune
    from fixer4d.scene import load_scene
    from fixer4d.train.config import Stage1Config
    from fixer4d.train.trainer import Trainer, model_from_clouds

    scene = load_scene(args.scene, scale=args.scale)
    cam = scene.cameras[scene.train_ids[0]]
    extra = {} if args.max_points is None else {"init_max_points": args.max_points}
    # statistics gathered every step, but no densify call inside the timed loop (it would change N)
    cfg = Stage1Config(iterations=args.warmup + args.iterations, backend=args.backend, progress=False,
                       densify_from=10 ** 9, densify_until=10 ** 9 + 1, **extra)
    model = model_from_clouds(depth_clouds(scene), scene, cfg)
    trainer = Trainer(model, scene, cfg)
    for _ in range(args.warmup):
        trainer.step()
    recs = []
    for _ in tqdm(range(args.iterations), desc="bench iteration", unit="it"):
        tic = time.perf_counter()
        rec = trainer.step()
        rec["t_total"] = time.perf_counter() - tic
        recs.append(rec)
    split = {k[2:]: float(np.mean([r[k] for r in recs])) for k in _PARTS}
    total = float(np.mean([r["t_total"] for r in recs]))
    split["other"] = max(total - sum(split.values()), 0.0)

    # one densify/prune call (size prunes on, as after the first opacity reset) on the statistics
    # gathered over the timed steps
    tic = time.perf_counter()
    counts = densify_and_prune(trainer.model, trainer.optimizer, trainer.stats, extent=trainer.extent,
                               grad_threshold=cfg.densify_grad_threshold, percent_dense=cfg.percent_dense,
                               max_gaussians=cfg.max_gaussians, prune_opacity=cfg.prune_opacity,
                               prune_world_scale=cfg.prune_world_scale, prune_screen_fraction=cfg.prune_screen_fraction,
                               generator=trainer.generator)
    densify_call = time.perf_counter() - tic

    result = {
        "benchmark": "iteration",
        "scene": scene.name, "resolution": [cam.width, cam.height], "num_frames": scene.num_frames,
        "num_gaussians": int(recs[-1]["num_gaussians"]), "views_per_step": cfg.views_per_step,
        "backend": args.backend, "render_backend": _backend_used(trainer, cam),
        "iterations": args.iterations, "seconds_per_iteration": total,
        "split_seconds": split,
        "densify_call_seconds": densify_call, "densify_call_counts": counts,
        "torch_threads": torch.get_num_threads(), "machine": platform.machine(),
        "python": platform.python_version(), "torch": torch.__version__,
    }
    print(f"{scene.name} {cam.width}x{cam.height}, {result['num_gaussians']} Gaussians, {cfg.views_per_step} views/it, "
          f"backend {result['render_backend']}")
    print(f"{'part':<12}{'s/it':>10}{'share':>8}")
    for k, v in split.items():
        print(f"{k:<12}{v:>10.4f}{100 * v / total:>7.1f}%")
    print(f"{'total':<12}{total:>10.4f}")
    print(f"one densify/prune call: {densify_call:.4f} s ({counts})")
    out = Path(args.out)
    write_json(out, result)
    print(f"-> {out}")
    return 0


def _backend_used(trainer, cam) -> str:
    from fixer4d.render.api import render

    import torch

    with torch.no_grad():
        return render(trainer.snapshot(0.0), cam, backend=trainer.config.backend).backend


if __name__ == "__main__":
    import sys

    sys.exit(main(sys.argv[1:]))

