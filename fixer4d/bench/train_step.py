"""`fixer4d bench train-step`: seconds per full training iteration (render, loss, backward,
Adam step) on the real Panoptic basketball frame 0, to set beside OpenSplat's CPU backend.

Conditions (the same as OpenSplat's measurement): one image per iteration, cycling over
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
last side-by-side figures (OPENSPLAT_CITED) are cited with their date and conditions, never
divided by.

Shared machines: ``--repeats R`` runs each row R times with the programs taking turns (ours,
OpenSplat, ours, OpenSplat, ...; each of our runs starts from the same fresh model) and reports
medians over the runs, with /proc/loadavg before and after every run in the row's "runs" list,
so that a change of load hits both programs alike. Wall and CPU seconds (all threads; OpenSplat's
from its /proc/PID/stat at its step lines) are both reported, and both ratios.
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
    # One rig-focus implementation: fixer4d.geometry.rig.
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
    parser.add_argument("--repeats", type=int, default=1,
                        help="runs per row, the programs taking turns (ours, OpenSplat, ...); medians")
    args = parser.parse_args(argv)
    if args.repeats < 1 or args.iters < 1:
        parser.error("--repeats and --iters must be at least 1")

    import torch
    from tqdm import tqdm

    from fixer4d.atomic import write_json
    from fixer4d.bench.opensplat import opensplat_info, run_opensplat, write_nerfstudio_project
    from fixer4d.bench.machine import machine_info, print_timing_caveats
    from fixer4d.errors import InputError
    from fixer4d.model.densify import make_adam
    from fixer4d.model.spacetime import ModelConfig, SpacetimeGaussians
    from fixer4d.scene import load_scene
    from fixer4d.train.trainer import ADAM_EPS

    try:
        from fixer4d.train.losses import stg_loss as loss_fn
        loss_name = "stg_loss (0.8 L1 + 0.2 D-SSIM)"
    except ImportError:
        loss_fn, loss_name = (lambda a, b: (a - b).abs().mean()), "L1"
    if not args.data.is_dir():
        raise InputError(f"bench train-step: Panoptic data not found at {args.data}; pass --data DIR")
    os_info = None
    if args.opensplat is not None:
        os_info = opensplat_info(args.opensplat)  # fail before the timed rows, not after
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
        targets = [torch.from_numpy(np.ascontiguousarray(scene.frame(0, i))) for i in range(len(cams))]

        def ours():
            model = SpacetimeGaussians.from_points(pts, cols, np.zeros(n), ModelConfig(), opacity=0.1)
            opt = make_adam(model.param_groups(LRS), eps=ADAM_EPS)
            return time_iterations(lambda i: _train_step(model, opt, cams[i], targets[i], args.backend, loss_fn),
                                   args.iters, len(cams))

        with tempfile.TemporaryDirectory(prefix="fixer4d-opensplat-") as tmp:
            theirs = None
            if args.opensplat is not None:
                project = write_nerfstudio_project(tmp, cams, [t.numpy() for t in targets], pts, cols)
                theirs = lambda: run_opensplat(args.opensplat, project, args.opensplat_iters,  # noqa: E731
                                               refine=os_info["refine"])
            runs = alternate(ours, theirs, args.repeats)
        rows.append(summarize_row(runs, backend=args.backend, n=n, width=cams[0].width, height=cams[0].height))
    result = {"rows": rows, "loss": loss_name, "bbox": [lo.tolist(), hi.tolist()], "cameras": len(cams),
              "data": str(args.data), "torch_threads": args.torch_threads, "machine": machine_info(reference=True),
              "iters": args.iters, "repeats": args.repeats, "opensplat_iters": args.opensplat_iters,
              "opensplat": str(args.opensplat) if args.opensplat is not None else "not run",
              "opensplat_version": os_info["version"] if os_info else None,
              "opensplat_cited": cited_json()}
    write_json(args.out, result)
    print_timing_caveats(result["machine"])
    print(format_table(rows))
    print(f"wrote {args.out}")
    return 0


def _train_step(model, opt, cam, target, backend: str, loss_fn) -> int:
    """One training iteration (render, loss, backward, Adam); returns its fragment count."""
    from fixer4d.render.api import render

    out = render(model.at(0.0), cam, backend=backend)
    loss = loss_fn(out.rgb, target)
    opt.zero_grad(set_to_none=True)
    loss.backward()
    opt.step()
    return int(out.n_fragments)


def time_iterations(step, iters: int, n_views: int) -> dict:
    """Median wall and process-CPU seconds of ``iters`` calls ``step(view)`` (views cycling),
    after one untimed warm-up call (JIT cache, allocators); mean fragments per call."""
    times, cpu_times, frags = [], [], []
    for it in range(iters + 1):
        c0 = time.process_time()
        t0 = time.perf_counter()
        fr = step(it % n_views)
        if it > 0:
            times.append(time.perf_counter() - t0)
            cpu_times.append(time.process_time() - c0)
            frags.append(fr)
    return {"s_per_iter": float(np.median(times)), "cpu_s_per_iter": float(np.median(cpu_times)),
            "fragments": float(np.mean(frags))}


def read_loadavg() -> str:
    """/proc/loadavg as it reads (1/5/15-min load, running/total tasks, last pid), or
    os.getloadavg() where there is no /proc."""
    try:
        with open("/proc/loadavg") as fh:
            return fh.read().strip()
    except OSError:
        return " ".join(f"{x:.2f}" for x in os.getloadavg())


def alternate(ours, theirs, repeats: int, loadavg=read_loadavg) -> list[dict]:
    """Run ``ours()`` and ``theirs()`` (None: ours only) taking turns, ``repeats`` times each,
    with the load read before and after every run: [{"fixer4d": ..., "opensplat": ...,
    "load_before"/"load_after", "opensplat_load_before"/"opensplat_load_after"}, ...]."""
    runs = []
    for _ in range(repeats):
        run = {"load_before": loadavg()}
        run["fixer4d"] = ours()
        run["load_after"] = loadavg()
        if theirs is not None:
            run["opensplat_load_before"] = loadavg()
            run["opensplat"] = theirs()
            run["opensplat_load_after"] = loadavg()
        runs.append(run)
    return runs


def _load1(line: str) -> float:
    return float(line.split()[0])


def summarize_row(runs: list[dict], backend: str, n: int, width: int, height: int) -> dict:
    """A table row from the alternating runs of one configuration: medians over the runs (each
    run's own figure is already a median over its iterations), every run kept under "runs"."""
    ours = [r["fixer4d"] for r in runs]
    s_it = float(np.median([o["s_per_iter"] for o in ours]))
    cpu_it = float(np.median([o["cpu_s_per_iter"] for o in ours]))
    fr = float(np.mean([o["fragments"] for o in ours]))
    loads = [_load1(r[k]) for r in runs for k in r if "load_" in k]
    row = {"backend": backend, "n_gaussians": n, "width": width, "height": height,
           "s_per_iter": round(s_it, 4), "fragments_per_pixel": round(fr / (width * height), 1),
           "ns_per_fragment": round(s_it * 1e9 / max(fr, 1.0), 2),
           # process CPU seconds (all threads): what the iteration costs however loaded
           # the machine is; on 2 idle cores the wall time lies between cpu/2 and cpu
           "cpu_s_per_iter": round(cpu_it, 4), "cpu_ns_per_fragment": round(cpu_it * 1e9 / max(fr, 1.0), 2),
           "load_avg": round(_load1(runs[0]["load_before"]), 2),
           "load_avg_range": [min(loads), max(loads)], "repeats": len(runs)}
    if all("opensplat" in r for r in runs):
        row.update(opensplat_row([r["opensplat"] for r in runs], s_it, cpu_it))
    row["runs"] = [{**r, "fixer4d": {k: round(v, 4) for k, v in r["fixer4d"].items()},
                    **({"opensplat": _opensplat_run_json(r["opensplat"])} if "opensplat" in r else {})}
                   for r in runs]
    return row


def _opensplat_run_json(res) -> dict:
    rnd = lambda v: None if v is None else round(v, 4)  # noqa: E731
    return {"s_per_iter": rnd(res.s_per_iter), "timing": res.timing, "cpu_s_per_iter": rnd(res.cpu_s_per_iter),
            "cpu_timing": res.cpu_timing, "cpu_s_total": rnd(res.cpu_s_total), "wall_s": rnd(res.wall_s)}


def opensplat_row(results, s_it: float, cpu_s_it: float | None = None) -> dict:
    """The OpenSplat fields of a row measured in this run: medians over its runs; speed-up = its
    s/iter over ours (wall), and its CPU s/iter over ours where both were measured."""
    if not isinstance(results, (list, tuple)):
        results = [results]
    res = results[0]
    os_it = float(np.median([r.s_per_iter for r in results]))
    row = {"opensplat_s_per_iter": round(os_it, 4), "opensplat_timing": res.timing,
           "opensplat_iters": res.iters, "opensplat_command": " ".join(res.command),
           "speedup_vs_opensplat": round(os_it / s_it, 2)}
    cpus = [r.cpu_s_per_iter for r in results if r.cpu_s_per_iter is not None]
    if cpus and len(cpus) == len(results):
        os_cpu = float(np.median(cpus))
        row.update({"opensplat_cpu_s_per_iter": round(os_cpu, 4), "opensplat_cpu_timing": res.cpu_timing})
        if cpu_s_it:
            row["cpu_speedup_vs_opensplat"] = round(os_cpu / cpu_s_it, 2)
    return row


def cited_json() -> dict:
    """The cited side-by-side figures (OPENSPLAT_CITED), JSON-ready (for the record, not for ratios)."""
    key = lambda k: f"{k[0]} {k[1]}x{k[2]}"  # noqa: E731
    return {name: ({key(k): v for k, v in val.items()} if isinstance(val, dict) else val)
            for name, val in OPENSPLAT_CITED.items()}


def format_table(rows: list[dict]) -> str:
    """The printed table. OpenSplat columns hold figures measured in this run, or "not run";
    the cited figures (OPENSPLAT_CITED) follow below, labelled, and are never divided by."""
    lines = [f"{'N':>7s} {'size':>8s} {'s/iter':>8s} {'cpu s':>8s} {'frag/px':>8s} {'ns/frag':>8s} "
             f"{'OpenSplat':>9s} {'OS cpu s':>8s} {'speed-up':>8s} {'cpu x':>7s} {'load':>5s}"]
    for r in rows:
        measured = r.get("opensplat_s_per_iter")
        os_col = f"{measured:9.3f}" if measured is not None else f"{'not run':>9s}"
        os_cpu = r.get("opensplat_cpu_s_per_iter")
        os_cpu_col = f"{os_cpu:8.3f}" if os_cpu is not None else f"{'-':>8s}"
        sp_col = f"{r['speedup_vs_opensplat']:7.2f}x" if measured is not None else f"{'-':>8s}"
        cpu_x = r.get("cpu_speedup_vs_opensplat")
        cpu_x_col = f"{cpu_x:6.2f}x" if cpu_x is not None else f"{'-':>7s}"
        lo, hi = r.get("load_avg_range", [r["load_avg"]] * 2)
        load_col = f"{r['load_avg']:5.2f}" if lo == hi else f"{lo:.2f}-{hi:.2f}"
        lines.append(f"{r['n_gaussians']:7d} {r['width']}x{r['height']:<4d} {r['s_per_iter']:8.3f} "
                     f"{r['cpu_s_per_iter']:8.3f} {r['fragments_per_pixel']:8.1f} {r['ns_per_fragment']:8.2f} "
                     f"{os_col} {os_cpu_col} {sp_col} {cpu_x_col} {load_col}")
    c = OPENSPLAT_CITED
    lines.append(f"cited, not measured here ({c['source']}), OpenSplat / fixer4d then, s/iter wall and CPU:")
    for k, v in c["opensplat_s_per_iter"].items():
        lines.append(f"  {k[0]:7d} {k[1]}x{k[2]}: {v:.3f} / {c['fixer4d_s_per_iter_then'][k]:.3f} wall, "
                     f"{c['opensplat_cpu_s_per_iter'][k]:.3f} / {c['fixer4d_cpu_s_per_iter_then'][k]:.3f} CPU")
    return "\n".join(lines)
