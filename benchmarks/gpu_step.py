"""fixer4d's stage-1 step against the bare loop it is built on, timed side by side in one process.

    python benchmarks/gpu_step.py [SCENE] [--model PLY] [--scale S] [--gaussians N] [--steps K]
                                  [--device cuda|cpu] --out FILE.json

The bare loop is gsplat's own training loop at its leanest (its simple_trainer's hot path): the
Gaussians as leaf tensors, the train frames on the device, per step one ``rasterization`` call
for the step's views, the same loss (0.8 L1 + 0.2 D-SSIM, ``stg_loss_device``, unweighted) and
a fused Adam; nothing read back. fixer4d's step is ``Trainer.train`` on the same scene,
resolution, Gaussians and views per step, in steady state (statistics gathered, no densification
or opacity reset among the timed steps), twice: with its default loss and with the bare loop's
(``moving_loss_weight=0``). The result is seconds per step of each and their ratios, and on CUDA
the synchronizations per step of each (``count_syncs``).

The Gaussians: ``--model`` (e.g. a run's model_stage1.ply, so the splats are a trained model's),
else the scene's ground-truth depth (synthetic scenes), capped at ``--gaussians``. On a machine
without CUDA (``--device cpu``) the bare loop rasterizes with fixer4d's CPU kernel, view by view.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import fixer4d  # noqa: F401  (sets the OpenMP wait policy before torch is imported)

# Steps before the timed ones: gsplat's kernels load, the allocator settles, fixer4d estimates
# its moving masks on its first step.
WARMUP_STEPS = 20
# Steps run after the timed ones under torch.cuda.set_sync_debug_mode("warn"), which warns at
# every call that makes the host wait for the GPU (gsplat's own included): two of fixer4d's
# 10-step reads, so the count per step includes them.
SYNC_STEPS = 20
# Learning rates of the bare loop: 3DGS's defaults (they do not change the time of a step).
BARE_LR = {"means": 1.6e-4, "quats": 1e-3, "log_scales": 5e-3, "opacity_logits": 5e-2, "colors": 2.5e-3}


def load_model(scene, model_path: Path | None, gaussians: int, config):
    """The model both loops train: ``model_path`` (capped to ``gaussians`` rows) or the
    ground-truth-depth init of a synthetic scene."""
    import torch

    if model_path is not None:
        from fixer4d.model.io import load_ply

        model = load_ply(model_path)
        if model.num_gaussians > gaussians:
            model.prune(torch.arange(model.num_gaussians) < gaussians)
        return model
    from fixer4d.bench.iteration import depth_clouds
    from fixer4d.train.model_init import model_from_clouds

    return model_from_clouds(depth_clouds(scene), scene, config)


def steady_config(steps: int, gaussians: int, device: str, **overrides):
    """A stage-1 config whose ``steps`` steps all gather statistics and none densifies or resets."""
    from fixer4d.train.config import TrainingConfig

    return TrainingConfig.for_iterations(steps, seed=0, progress=False, device=device, init_max_points=gaussians,
                                       max_gaussians=gaussians, densify_from=steps, densify_until=steps,
                                       opacity_reset_every=steps + 1, **overrides)


def synchronize(device) -> None:
    import torch

    if device.type == "cuda":
        torch.cuda.synchronize(device)


def count_syncs(device, run) -> float | None:
    """Host waits per step of ``run(SYNC_STEPS)`` on CUDA (None elsewhere): the warnings of
    torch's sync debug mode, one per synchronizing call."""
    import warnings

    import torch

    if device.type != "cuda":
        return None
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        torch.cuda.set_sync_debug_mode("warn")
        try:
            run(SYNC_STEPS)
        finally:
            torch.cuda.set_sync_debug_mode("default")
    return sum("synchroniz" in str(w.message) for w in caught) / SYNC_STEPS


def time_fixer4d(scene, model, config, steps: int) -> tuple[float, float | None]:
    """(seconds per step of ``Trainer.train`` over ``steps`` steps after WARMUP_STEPS, host waits
    per step)."""
    from fixer4d.train.trainer import Trainer

    trainer = Trainer(model, scene, config)
    trainer.train(WARMUP_STEPS)
    synchronize(trainer.device)
    tic = time.perf_counter()
    trainer.train(steps)
    synchronize(trainer.device)
    seconds = (time.perf_counter() - tic) / steps
    return seconds, count_syncs(trainer.device, trainer.train)


def time_bare(scene, model, device, views_per_step: int, steps: int) -> tuple[float, float | None]:
    """(seconds per step of the bare loop (module docstring) over ``steps`` steps after
    WARMUP_STEPS, host waits per step)."""
    import numpy as np
    import torch

    from fixer4d.train.losses import stg_loss_device

    snap = model.at(0.5).detach()
    params = {"means": snap.means, "quats": snap.quats, "log_scales": snap.scales.log(),
              "opacity_logits": torch.logit(snap.opacities.clamp(1e-4, 1 - 1e-4)), "colors": snap.colors}
    params = {k: v.detach().to(device).contiguous().requires_grad_(True) for k, v in params.items()}
    optimizer = torch.optim.Adam([{"params": [p], "lr": BARE_LR[k]} for k, p in params.items()], eps=1e-15,
                                 fused=True)
    ids = list(scene.train_ids)
    frames = torch.from_numpy(np.stack([[scene.frame(f, c) for f in range(scene.num_frames)] for c in ids])).to(device)
    cameras = [scene.cameras[c] for c in ids]
    background = torch.zeros(3, device=device)
    rasterize = _gsplat_views(cameras, device, background) if device.type == "cuda" else _cpu_views(cameras,
                                                                                                    background)
    rng = np.random.default_rng(0)
    k = min(views_per_step, len(ids))

    def step() -> None:
        frame = int(rng.integers(0, scene.num_frames))
        views = [int(v) for v in rng.choice(len(ids), size=k, replace=False)]
        rgb = rasterize(params, views)
        loss = k * stg_loss_device(rgb, torch.stack([frames[v, frame] for v in views]))
        loss.backward()
        optimizer.step()
        optimizer.zero_grad(set_to_none=True)

    def run(n: int) -> None:
        for _ in range(n):
            step()

    run(WARMUP_STEPS)
    synchronize(device)
    tic = time.perf_counter()
    run(steps)
    synchronize(device)
    seconds = (time.perf_counter() - tic) / steps
    return seconds, count_syncs(device, run)


def _gsplat_views(cameras, device, background):
    """``rasterize(params, views) -> (V, H, W, 3)``: one ``gsplat.rasterization`` call."""
    import torch
    from gsplat import rasterization

    from fixer4d.render.gsplat_backend import camera_matrices

    viewmats, Ks = camera_matrices(cameras, device)
    width, height = cameras[0].width, cameras[0].height

    def rasterize(p, views):
        # stacked rows, not viewmats[views]: a host index list would be copied to the GPU each step
        rgb, _, _ = rasterization(p["means"], p["quats"], p["log_scales"].exp(), torch.sigmoid(p["opacity_logits"]),
                                  p["colors"], torch.stack([viewmats[v] for v in views]),
                                  torch.stack([Ks[v] for v in views]), width, height, packed=False,
                                  backgrounds=background[None].expand(len(views), 3))
        return rgb

    return rasterize


def _cpu_views(cameras, background):
    """``rasterize(params, views) -> (V, H, W, 3)`` with fixer4d's CPU kernel, view by view."""
    import torch

    from fixer4d.model.snapshot import Snapshot
    from fixer4d.render.api import render

    def rasterize(p, views):
        snap = Snapshot(p["means"], p["quats"], p["log_scales"].exp(), torch.sigmoid(p["opacity_logits"]), p["colors"])
        return torch.stack([render(snap, cameras[v], background, backend="cpu").rgb for v in views])

    return rasterize


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scene", nargs="?", default="demo", help="a scene as `fixer4d reconstruct` takes it")
    parser.add_argument("--model", type=Path, default=None, help="the Gaussians (PLY); default: the scene's depth")
    parser.add_argument("--scale", type=float, default=1.0, help="image scale of the scene")
    parser.add_argument("--frames", default=None, metavar="A:B", help="frame range of the scene (default: all)")
    parser.add_argument("--gaussians", type=int, default=40_000, help="at most this many Gaussians")
    parser.add_argument("--steps", type=int, default=200, help="timed steps of each loop")
    parser.add_argument("--device", choices=("cuda", "cpu"), default=None, help="default: cuda where usable")
    parser.add_argument("--out", type=Path, required=True, help="JSON result file")
    args = parser.parse_args(argv)
    if args.steps < 1 or args.gaussians < 1:
        parser.error("--steps and --gaussians must be >= 1")

    import torch

    from fixer4d.atomic import write_json
    from fixer4d.bench.machine import machine_info
    from fixer4d.scene import load_scene
    from fixer4d.train.device import training_device

    device = training_device(args.device or "auto", "auto")
    frames = None if args.frames is None else tuple(int(x) for x in args.frames.split(":"))
    scene = load_scene(args.scene, scale=args.scale, frame_range=frames)
    total = WARMUP_STEPS + args.steps + SYNC_STEPS
    rows, syncs = {}, {}
    for name, overrides in (("fixer4d", {}), ("fixer4d_same_loss", {"moving_loss_weight": 0.0})):
        config = steady_config(total, args.gaussians, device.type, **overrides)
        model = load_model(scene, args.model, args.gaussians, config)
        rows[name], syncs[name] = time_fixer4d(scene, model, config, args.steps)
    config = steady_config(total, args.gaussians, device.type)
    model = load_model(scene, args.model, args.gaussians, config)
    rows["bare"], syncs["bare"] = time_bare(scene, model, device, config.views_per_step, args.steps)
    camera = scene.cameras[scene.train_ids[0]]
    result = {"scene": args.scene, "scale": args.scale, "width": camera.width, "height": camera.height,
              "frames": scene.num_frames, "gaussians": model.num_gaussians, "views_per_step": config.views_per_step,
              "steps": args.steps, "warmup_steps": WARMUP_STEPS, "device": str(device),
              "gpu": torch.cuda.get_device_name(0) if device.type == "cuda" else None,
              "s_per_step": {k: round(v, 6) for k, v in rows.items()},
              "ratio_to_bare": round(rows["fixer4d_same_loss"] / rows["bare"], 3),
              "ratio_default_loss_to_bare": round(rows["fixer4d"] / rows["bare"], 3),
              "cuda_syncs_per_step": syncs, "sync_steps": SYNC_STEPS,
              "machine": machine_info(), "command": " ".join(["python", "benchmarks/gpu_step.py", *(argv or sys.argv[1:])])}
    write_json(args.out, result)
    print(f"{device}: fixer4d {rows['fixer4d'] * 1e3:.2f} ms/step ({rows['fixer4d_same_loss'] * 1e3:.2f} with the bare "
          f"loop's loss), bare loop {rows['bare'] * 1e3:.2f} ms/step: ratio {result['ratio_to_bare']}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
