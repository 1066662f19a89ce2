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

from fixer4d.bench import positive_int

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
    args = _parser().parse_args(argv)
    if args.model_terms:
        return _terms_main(args)
    return _iteration_main(args)


def _parser() -> argparse.ArgumentParser:
    """The command line of ``fixer4d bench iteration`` (plain timing, or --model-terms)."""
    parser = argparse.ArgumentParser(prog="fixer4d bench iteration", description=__doc__.splitlines()[0])
    parser.add_argument("--scene", default="demo")
    parser.add_argument("--scale", type=float, default=1.0, help="image scale of the scene")
    parser.add_argument("--iterations", type=positive_int, default=30, help="timed iterations")
    parser.add_argument("--warmup", type=int, default=3, help="untimed iterations first (JIT compilation)")
    parser.add_argument("--backend", default="auto")
    parser.add_argument("--max-points", type=int, default=None, help="init point cap (default: TrainingConfig's)")
    parser.add_argument("--out", default="benchmarks/results/iteration.json")
    parser.add_argument("--model-terms", action="store_true",
                        help="instead: seconds per iteration with model terms auto vs all vs the per-frame init "
                             "(decomposed MVS init of every --init-stride-th frame; see terms_comparison)")
    parser.add_argument("--effects", action="store_true", dest="model_terms", help=argparse.SUPPRESS)  # former name
    parser.add_argument("--init", default=None, help="with --model-terms: a decomposed init folder to reuse "
                                                     "(default: computed into a temporary folder)")
    parser.add_argument("--init-stride", type=int, default=4, help="with --model-terms: init frame stride (the pipeline's)")
    parser.add_argument("--frames", default=None, metavar="A:B",
                        help="the clip, half-open (the run's frame_range, e.g. 0:30 for the README's Panoptic "
                             "command; an --init's times are clip times)")
    return parser


def _iteration_main(args) -> int:
    """Seconds per stage-1 iteration split by part, and one densify/prune call (see the module
    docstring); writes ``args.out``."""
    import torch
    from tqdm import tqdm

    from fixer4d.atomic import write_json
    from fixer4d.model.densify import densify_and_prune
    from fixer4d.scene import load_scene
    from fixer4d.train.config import TrainingConfig
    from fixer4d.train.model_init import model_from_clouds
    from fixer4d.train.trainer import Trainer

    scene = load_scene(args.scene, scale=args.scale, frame_range=_clip(args.frames))
    cam = scene.cameras[scene.train_ids[0]]
    extra = {} if args.max_points is None else {"init_max_points": args.max_points}
    # statistics gathered every step, but no densify call inside the timed loop (it would change N)
    cfg = TrainingConfig(iterations=args.warmup + args.iterations, backend=args.backend, progress=False,
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

    # one densify/prune call (the configured size prunes, as after the first opacity reset) on
    # the statistics gathered over the timed steps
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


# Rows of the model-terms comparison: name -> (use the decomposed init?, model-terms mode).
TERM_ROWS = {"per_frame_all": (False, None), "decomposed_all": (True, "all"), "decomposed_auto": (True, "auto")}


def terms_comparison(scene, init, cfg, iterations: int, warmup: int) -> dict:
    """Seconds per stage-1 iteration of the same scene and init at equal settings (``cfg``),
    with every term on vs terms by evidence, measured in one process and interleaved
    step by step (so a load change on a shared machine hits every row alike).

    init: a DecomposedInit. Rows (TERM_ROWS): the per-frame clouds (static cloud repeated in
    every init frame, every Gaussian dynamic with the default terms: the path before the
    decomposition), the decomposed init with mode all, and with mode auto. Densification is
    off inside the timed loop (it would change N). Returns {row: {seconds_per_iteration,
    num_gaussians, num_dynamic, config, split_seconds}} plus ratios against auto.
    """
    import time

    from fixer4d.model.terms import ModelTermsConfig
    from fixer4d.train.model_init import model_from_init
    from fixer4d.train.trainer import Trainer

    for f in range(scene.num_frames):  # decode every train frame first: no row pays the loading
        for c in scene.train_ids:
            scene.frame(f, c)
    trainers = {}
    for name, (decomposed, mode) in TERM_ROWS.items():
        src = init if decomposed else init.frame_clouds()
        terms = ModelTermsConfig(mode=mode, revise=False) if mode else None
        model, _ = model_from_init(src, scene, cfg, terms)
        trainers[name] = Trainer(model, scene, cfg)
    for _ in range(warmup):
        for t in trainers.values():
            t.step()
    recs: dict[str, list] = {k: [] for k in trainers}
    for _ in range(iterations):
        for name, t in trainers.items():
            tic = time.perf_counter()
            rec = t.step()
            rec["t_total"] = time.perf_counter() - tic
            recs[name].append(rec)
    rows = {}
    for name, t in trainers.items():
        r = recs[name]
        rows[name] = {"seconds_per_iteration": float(np.median([x["t_total"] for x in r])),
                      "num_gaussians": t.model.num_gaussians, "num_dynamic": t.model.num_dynamic,
                      "config": t.model.config.to_dict(),
                      "split_seconds": {k[2:]: float(np.median([x[k] for x in r])) for k in _PARTS}}
    auto = rows["decomposed_auto"]["seconds_per_iteration"]
    return {"rows": rows, "speedup_auto_vs": {k: v["seconds_per_iteration"] / auto for k, v in rows.items()}}


def _clip(frames: str | None) -> tuple[int, int] | None:
    """``--frames A:B`` -> (A, B), checked against the scene when it opens."""
    from fixer4d.scene import parse_frame_range

    return None if frames is None else tuple(parse_frame_range(frames))


def _terms_main(args) -> int:
    import os
    import tempfile

    import torch

    from fixer4d.atomic import write_json
    from fixer4d.init import run_init
    from fixer4d.init.decompose import DecomposedInit
    from fixer4d.scene import load_scene
    from fixer4d.train.config import TrainingConfig

    clip = _clip(args.frames)
    scene = load_scene(args.scene, scale=args.scale, frame_range=clip)
    frames = list(range(0, scene.num_frames, max(1, args.init_stride)))
    if args.init is None:
        with tempfile.TemporaryDirectory() as tmp:
            run_init(scene, "mvs", tmp, frames=frames, progress=False)
            init = DecomposedInit.load(tmp)
    else:
        init = DecomposedInit.load(args.init)
    extra = {} if args.max_points is None else {"init_max_points": args.max_points}
    cfg = TrainingConfig(iterations=10 ** 9, backend=args.backend, progress=False,
                       densify_from=10 ** 9, densify_until=10 ** 9 + 1, **extra)
    result = {"benchmark": "iteration-effects", "scene": scene.name, "frame_range": clip, "init_frames": frames,
              "iterations": args.iterations, "warmup": args.warmup, "init_max_points": cfg.init_max_points,
              "torch_threads": torch.get_num_threads(), "load_average": list(os.getloadavg()),
              **terms_comparison(scene, init, cfg, args.iterations, args.warmup)}
    result["load_average_after"] = list(os.getloadavg())
    for name, r in result["rows"].items():
        print(f"{name:<18}{r['seconds_per_iteration']:>9.4f} s/it  {r['num_gaussians']:>7} Gaussians "
              f"({r['num_dynamic']} dynamic)  {result['speedup_auto_vs'][name]:.2f}x auto")
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

