"""`fixer4d bench train-step`: seconds per full training iteration (render, loss, backward,
Adam step) on the real Panoptic basketball frame 0, to set beside OpenSplat's CPU backend.

Conditions (issue 3, the same as OpenSplat's measurement): one image per iteration, cycling over
the scene's cameras at frame 0; N random points uniform in a box; scales from the 3-NN distance;
opacity 0.1; 30k and 100k Gaussians at 320x180 and 640x360. The repository has no triangulation
of this scene yet, so the box is where the given cameras' views overlap: points of a grid over
the camera centres' bounding box that project inside every image in front of every camera
(written to the JSON as "bbox"). Fragments (Gaussian-pixel pairs blended) are reported so runs
compare per fragment.

OpenSplat side by side: with ``--opensplat PATH`` the same cameras, images, points and sizes are
written as a nerfstudio project and the user's OpenSplat binary is run on it (CPU backend,
fixer4d/bench/opensplat.py); both seconds per iteration are reported and the speed-up is the
ratio of the two measured here. Without a binary the OpenSplat column says "not run" and the
side-by-side figures of issue 15 are cited with their date and conditions, never divided by.
"""
from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from fixer4d.bench.opensplat import OPENSPLAT_CITED

DEFAULT_OUT = Path("benchmarks/results/train_step.json")
DEFAULT_DATA = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "panoptic_basketball"
COUNTS = (30_000, 100_000)
SCALES = (0.5, 1.0)  # of 640x360: 320x180 and 640x360
BOX_GRID = 64  # samples per axis when locating the cameras' common view
# STGS-like Adam learning rates (position rates scaled by the rig's extent as in 3DGS)
LRS = {"means": 1.6e-4, "log_scales": 5e-3, "quats": 1e-3, "opacity_logits": 5e-2, "colors": 2.5e-3,
       "sh_rest": 1.25e-4, "t_center": 1e-4, "t_log_scale": 3e-3, "motion": 1e-4, "omega": 1e-4}


def common_view_box(cameras) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned box of the grid points seen by every camera.

    The grid spans the camera centres and their mirror images through the point nearest to all
    optical axes (where the rig looks), so it covers the observed volume of an inward-facing rig.
    """
    # One rig-focus implementation (issue 13.4): fixer4d.geometry.rig.
    from fixer4d.geometry.rig import rig_focus
    centres = np.stack([c.center for c in cameras])
    focus = rig_focus(cameras)
    span = np.concatenate([centres, 2.0 * focus - centres])
    lo, hi = span.min(0), span.max(0)
    axes = [np.linspace(lo[i], hi[i], BOX_GRID) for i in range(3)]
    pts = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    seen = np.ones(len(pts), bool)
    for cam in cameras:
        uv, z = cam.project(pts)
        with np.errstate(invalid="ignore"):
            seen &= (z > 0) & (uv[:, 0] >= 0) & (uv[:, 0] < cam.width) & (uv[:, 1] >= 0) & (uv[:, 1] < cam.height)
    if not seen.any():
        raise RuntimeError("the cameras share no common view; cannot place random points")
    return pts[seen].min(0), pts[seen].max(0)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="fixer4d bench train-step", description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help="JSON output file")
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA, help="Panoptic basketball folder")
    parser.add_argument("--iters", type=int, default=10, help="timed iterations per row (after one warm-up)")
    parser.add_argument("--backend", default="cpu", help="render backend")
    parser.add_argument("--torch-threads", type=int, default=1,
                        help="torch intra-op threads (the numba kernels use every core regardless)")
    parser.add_argument("--opensplat", type=Path, default=None, metavar="PATH",
                        help="an OpenSplat binary (CPU build) to run on the same inputs, side by side")
    parser.add_argument("--opensplat-iters", type=int, default=60,
                        help="OpenSplat iterations per row (timed from its progress lines)")
    args = parser.parse_args(argv)

    import torch
    from tqdm import tqdm

    from fixer4d.atomic import write_json
    from fixer4d.bench.opensplat import resolve_binary, run_opensplat, write_nerfstudio_project
    from fixer4d.bench.raster import machine_info
    from fixer4d.errors import InputError
    from fixer4d.model.spacetime import ModelConfig, SpacetimeGaussians
    from fixer4d.render.api import render
    from fixer4d.scene import load_scene

    try:
        from fixer4d.train.losses import stg_loss as loss_fn
        loss_name = "stg_loss (0.8 L1 + 0.2 D-SSIM)"
    except ImportError:
        loss_fn, loss_name = (lambda a, b: (a - b).abs().mean()), "L1"
    if not args.data.is_dir():
        raise InputError(f"bench train-step: Panoptic data not found at {args.data}; pass --data DIR")
    if args.opensplat is not None:
        resolve_binary(args.opensplat)  # fail before the timed rows, not after
    torch.set_num_threads(args.torch_threads)

    rows = []
    jobs = [(n, s) for s in SCALES for n in COUNTS]
    for n, scale in tqdm(jobs, desc="bench train-step"):
        scene = load_scene(args.data, scale=scale)
        cams = list(scene.cameras)
        lo, hi = common_view_box(cams)
        rng = np.random.default_rng(0)
        pts = rng.uniform(lo, hi, (n, 3))
        cols = rng.uniform(0, 1, (n, 3))
        model = SpacetimeGaussians.from_points(pts, cols, np.zeros(n), ModelConfig(), opacity=0.1)
        opt = torch.optim.Adam(model.param_groups(LRS), eps=1e-15)
        targets = [torch.from_numpy(np.ascontiguousarray(scene.frame(0, i))) for i in range(len(cams))]
        times, cpu_times, frags = [], [], []
        for it in range(args.iters + 1):
            i = it % len(cams)
            c0 = time.process_time()
            t0 = time.perf_counter()
            out = render(model.at(0.0), cams[i], backend=args.backend)
            loss = loss_fn(out.rgb, targets[i])
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()
            if it > 0:  # the first iteration loads the JIT cache and warms allocators
                times.append(time.perf_counter() - t0)
                cpu_times.append(time.process_time() - c0)
                frags.append(out.n_fragments)
        w, h = cams[0].width, cams[0].height
        s_it = float(np.median(times))
        fr = float(np.mean(frags))
        row = {"backend": args.backend, "n_gaussians": n, "width": w, "height": h,
               "s_per_iter": round(s_it, 4), "fragments_per_pixel": round(fr / (w * h), 1),
               "ns_per_fragment": round(s_it * 1e9 / max(fr, 1.0), 2),
               # process CPU seconds (all threads): what the iteration costs however loaded
               # the machine is; on 2 idle cores the wall time lies between cpu/2 and cpu
               "cpu_s_per_iter": round(float(np.median(cpu_times)), 4),
               "load_avg": round(os.getloadavg()[0], 2)}
        if args.opensplat is not None:
            with tempfile.TemporaryDirectory(prefix="fixer4d-opensplat-") as tmp:
                project = write_nerfstudio_project(tmp, cams, [t.numpy() for t in targets], pts, cols)
                res = run_opensplat(args.opensplat, project, args.opensplat_iters)
            row.update(opensplat_row(res, s_it))
            row["load_avg_after_opensplat"] = round(os.getloadavg()[0], 2)
        rows.append(row)
    result = {"rows": rows, "loss": loss_name, "bbox": [lo.tolist(), hi.tolist()], "cameras": len(cams),
              "data": str(args.data), "torch_threads": args.torch_threads, "machine": machine_info(),
              "opensplat": str(args.opensplat) if args.opensplat is not None else "not run",
              "opensplat_cited": cited_json()}
    write_json(args.out, result)
    print(format_table(rows))
    print(f"wrote {args.out}")
    return 0


def opensplat_row(res, s_it: float) -> dict:
    """The OpenSplat fields of a row measured in this run (speed-up = its s/iter over ours)."""
    return {"opensplat_s_per_iter": round(res.s_per_iter, 4), "opensplat_timing": res.timing,
            "opensplat_iters": res.iters, "opensplat_command": " ".join(res.command),
            "speedup_vs_opensplat": round(res.s_per_iter / s_it, 2)}


def cited_json() -> dict:
    """The cited side-by-side figures of issue 15, JSON-ready (for the record, not for ratios)."""
    key = lambda k: f"{k[0]} {k[1]}x{k[2]}"  # noqa: E731
    return {"source": OPENSPLAT_CITED["source"],
            "opensplat_s_per_iter": {key(k): v for k, v in OPENSPLAT_CITED["opensplat_s_per_iter"].items()},
            "fixer4d_s_per_iter_then": {key(k): v for k, v in OPENSPLAT_CITED["fixer4d_s_per_iter_then"].items()}}


def format_table(rows: list[dict]) -> str:
    """The printed table. OpenSplat columns hold figures measured in this run, or "not run";
    the cited figures of issue 15 follow below, labelled, and are never divided by."""
    lines = [f"{'N':>7s} {'size':>8s} {'s/iter':>8s} {'cpu s':>8s} {'frag/px':>8s} {'ns/frag':>8s} "
             f"{'OpenSplat':>9s} {'speed-up':>8s} {'load':>5s}"]
    for r in rows:
        measured = r.get("opensplat_s_per_iter")
        os_col = f"{measured:9.3f}" if measured is not None else f"{'not run':>9s}"
        sp_col = f"{r['speedup_vs_opensplat']:7.2f}x" if measured is not None else f"{'-':>8s}"
        lines.append(f"{r['n_gaussians']:7d} {r['width']}x{r['height']:<4d} {r['s_per_iter']:8.3f} "
                     f"{r['cpu_s_per_iter']:8.3f} {r['fragments_per_pixel']:8.1f} {r['ns_per_fragment']:8.2f} "
                     f"{os_col} {sp_col} {r['load_avg']:5.2f}")
    lines.append(f"cited, not measured here ({OPENSPLAT_CITED['source']}), s/iter OpenSplat / fixer4d then:")
    for k, v in OPENSPLAT_CITED["opensplat_s_per_iter"].items():
        lines.append(f"  {k[0]:7d} {k[1]}x{k[2]}: {v:.3f} / {OPENSPLAT_CITED['fixer4d_s_per_iter_then'][k]:.3f}")
    return "\n".join(lines)
