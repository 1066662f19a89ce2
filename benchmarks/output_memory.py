"""Peak memory of the output paths: a ply-sequence export and an H.264 render of a long clip.

    python benchmarks/output_memory.py --out /tmp/om [--gaussians 60000] [--frames 150] [--json r.json]

A synthetic model of realistic size (``--gaussians``, every effect on, 70% dynamic, SH degree 1)
is saved to OUT/model.ply; then each task runs in a fresh process (``fixer4d export`` /
``fixer4d render`` on that file) at ``--frames`` and at ``SHORT_FRAMES`` frames, and the child's
peak resident set size (getrusage ru_maxrss) is reported. Streaming means the long clip peaks
where the short one does: memory grows with one frame, not with the clip. 640x360 frames, the
camera path is a 150-frame orbit written as a nerfstudio camera_path.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

WIDTH, HEIGHT = 640, 360
SHORT_FRAMES = 10


def make_inputs(out: Path, n: int, frames: int) -> tuple[Path, Path]:
    import torch

    from fixer4d.geometry.camera import Camera
    from fixer4d.geometry.trajectory import Trajectory, save_nerfstudio
    from fixer4d.model.io import save_ply
    from fixer4d.model.spacetime import ModelConfig, SpacetimeGaussians

    rng = np.random.default_rng(0)
    pts = rng.normal(size=(n, 3)) * np.array([1.0, 0.5, 1.0])
    model = SpacetimeGaussians.from_points(pts, rng.uniform(0.1, 0.9, size=(n, 3)), rng.uniform(0, 1, size=n),
                                           ModelConfig(sh_degree=1), opacity=0.5, scales=rng.uniform(0.005, 0.03, (n, 3)),
                                           dynamic=rng.uniform(size=n) < 0.7)
    g = torch.Generator().manual_seed(0)
    with torch.no_grad():
        model.motion.copy_(torch.randn(model.motion.shape, generator=g) * 0.2)
        model.omega.copy_(torch.randn(n, 4, generator=g) * 0.3)
        model.t_log_scale.copy_(torch.log(torch.rand(n, generator=g) * 0.4 + 0.1))
        model.sh_rest.copy_(torch.randn(model.sh_rest.shape, generator=g) * 0.1)
    model_path = save_ply(model, out / "model.ply")
    angles = np.linspace(0, np.pi / 2, frames)
    cams = [Camera.look_at([4 * np.sin(a), -0.5, -4 * np.cos(a)], [0, 0, 0], up=(0, -1, 0), fov_y=np.radians(40),
                           width=WIDTH, height=HEIGHT, name=f"o{k}") for k, a in enumerate(angles)]
    path = save_nerfstudio(Trajectory("orbit", cams, np.linspace(0, 1, frames), times=np.arange(frames) / frames),
                           out / f"orbit{frames}.json", fps=30.0)
    return model_path, path


# The child runs the CLI in-process and reports its own peak RSS (getrusage of itself), so each
# measurement is that one command's, whatever ran before it.
CHILD = ("import resource, sys; from fixer4d.cli import main; rc = main(sys.argv[1:]); "
         "print('PEAK_KIB', resource.getrusage(resource.RUSAGE_SELF).ru_maxrss, file=sys.stderr); sys.exit(rc)")


def measure(args: list[str]) -> dict:
    """Run ``fixer4d ARGS`` in a child process: its wall time and peak RSS (MiB)."""
    t0 = time.perf_counter()
    done = subprocess.run([sys.executable, "-c", CHILD, *args], check=True, stdout=subprocess.DEVNULL,
                          stderr=subprocess.PIPE, text=True)
    seconds = time.perf_counter() - t0
    peak_kib = int(next(line.split()[1] for line in done.stderr.splitlines() if line.startswith("PEAK_KIB")))
    return {"cmd": "fixer4d " + " ".join(args), "seconds": round(seconds, 1), "peak_rss_mib": round(peak_kib / 1024, 1)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--gaussians", type=int, default=60000)
    ap.add_argument("--frames", type=int, default=150)
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    model_path, long_path = make_inputs(args.out, args.gaussians, args.frames)
    _, short_path = make_inputs(args.out, args.gaussians, SHORT_FRAMES)
    rows = {}
    for frames, cam_path in ((SHORT_FRAMES, short_path), (args.frames, long_path)):
        rows[f"export_ply_sequence_{frames}"] = measure(
            ["export", str(model_path), "--format", "ply-sequence", "--frames", str(frames), "--quiet",
             "--out", str(args.out / f"seq{frames}")])
        rows[f"render_mp4_{frames}"] = measure(
            ["render", str(model_path), "--camera-path", str(cam_path), "--quiet", "--out", str(args.out / f"v{frames}.mp4")])
        print(json.dumps({k: rows[k] for k in list(rows)[-2:]}), flush=True)
    result = {"gaussians": args.gaussians, "size": f"{WIDTH}x{HEIGHT}", "rows": rows}
    print(json.dumps(result, indent=2))
    if args.json:
        args.json.write_text(json.dumps(result, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
