"""Stage 1 on each training device of this machine, side by side: what a GPU buys in time and
whether the model it trains is as good.

    python benchmarks/training_device.py [SCENE] [--devices cpu,cuda] [--set KEY=VALUE ...] --out FILE.json

For every device the scene is reconstructed as `fixer4d reconstruct SCENE --set
training.device=DEVICE` does (the dense init, stage 1 from it, the held-out evaluation), in its own
run folder, one device after the other in this process, on the same machine: each device's
stage-1 seconds, seconds per iteration, held-out PSNR (all / moving / static pixels) and final
Gaussian count. The init is computed once per device (no stage cache: the cache's keys leave
the device out, so it would hand the second device the first one's model). Default devices:
the CPU, and CUDA where torch sees a GPU and gsplat is installed. The JSON records the machine
(CPU topology, load, threads) and the GPU, torch and gsplat versions.
"""
from __future__ import annotations

import argparse
import importlib.metadata
import sys
import tempfile
import time
from pathlib import Path

import fixer4d  # noqa: F401  (sets the OpenMP wait policy before torch is imported)


def default_devices() -> list[str]:
    """["cpu"], plus "cuda" where stage 1 can train there through gsplat."""
    import torch

    from fixer4d.render.gsplat_backend import unavailable_reason

    return ["cpu"] + (["cuda"] if torch.cuda.is_available() and unavailable_reason() is None else [])


def gpu_info() -> dict:
    """The GPU and the CUDA-side versions (empty where there is no GPU)."""
    import torch

    if not torch.cuda.is_available():
        return {}
    out = {"name": torch.cuda.get_device_name(0), "cuda": torch.version.cuda}
    try:
        out["gsplat"] = importlib.metadata.version("gsplat")
    except importlib.metadata.PackageNotFoundError:
        out["gsplat"] = None
    return out


def reconstruct_on(scene: str, device: str, sets: dict, out: Path) -> dict:
    """Init + stage 1 + held-out evaluation of ``scene`` training on ``device`` into ``out``."""
    from fixer4d.model.io import load_ply
    from fixer4d.pipeline import report as R
    from fixer4d.cli.reconstruct import RECONSTRUCT_ONLY
    from fixer4d.pipeline.config import resolve
    from fixer4d.pipeline.run import run_pipeline

    config = resolve(scene, overrides={**sets, **RECONSTRUCT_ONLY, "training.device": device, "training.progress": False})
    t0 = time.perf_counter()
    report = run_pipeline(config, out, progress=False)
    wall = time.perf_counter() - t0
    row = next(r for r in report["rows"] if r["method"] == R.ROW_MVS)
    seconds = report["stage_seconds"]
    return {"device": device, "iterations": config.training.iterations,
            "stage1_seconds": round(seconds["stage1"], 2),
            "s_per_iter": round(seconds["stage1"] / max(config.training.iterations, 1), 5),
            "init_seconds": round(seconds.get("init_mvs", float("nan")), 2), "run_seconds": round(wall, 2),
            "psnr": row["psnr"], "psnr_dynamic": row["psnr_dynamic"], "psnr_static": row["psnr_static"],
            "dssim1": row["dssim1"], "lpips": row["lpips"],
            "gaussians": load_ply(Path(out) / "model_stage1.ply").num_gaussians}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scene", nargs="?", default="demo", help="a scene as `fixer4d reconstruct` takes it")
    parser.add_argument("--devices", default=None, help="comma-separated devices (default: cpu, and cuda if usable)")
    parser.add_argument("--set", dest="sets", action="append", default=[], metavar="KEY=VALUE")
    parser.add_argument("--runs", type=Path, default=None, help="folder for the run folders (default: a temporary one)")
    parser.add_argument("--out", type=Path, required=True, help="JSON result file")
    args = parser.parse_args(argv)

    from fixer4d.atomic import write_json
    from fixer4d.bench.machine import machine_info, print_timing_caveats
    from fixer4d.pipeline.config_tree import parse_set_overrides
    from fixer4d.pipeline.run_folder import source_commit

    devices = args.devices.split(",") if args.devices else default_devices()
    sets = parse_set_overrides(args.sets)
    machine = machine_info()
    with tempfile.TemporaryDirectory(prefix="fixer4d-devices-") as tmp:
        root = args.runs or Path(tmp)
        rows = []
        for device in devices:
            rows.append(reconstruct_on(args.scene, device, sets, root / device))
            r = rows[-1]
            print(f"{device:5s} stage 1 {r['stage1_seconds']:8.1f} s ({r['s_per_iter'] * 1e3:7.1f} ms/it), "
                  f"held-out PSNR {r['psnr']:.2f} dB, {r['gaussians']} Gaussians", flush=True)
    cpu = next((r for r in rows if r["device"] == "cpu"), None)
    for r in rows:
        if cpu is not None and r is not cpu:
            r["speedup_vs_cpu"] = round(cpu["stage1_seconds"] / r["stage1_seconds"], 2)
            r["psnr_minus_cpu"] = round(r["psnr"] - cpu["psnr"], 3)
    write_json(args.out, {"scene": args.scene, "sets": sets, "rows": rows, "commit": source_commit(),
                          "machine": machine, "gpu": gpu_info(),
                          "command": " ".join(["python", "benchmarks/training_device.py", *(argv or sys.argv[1:])])})
    print_timing_caveats(machine)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
