"""Run a user-built OpenSplat binary on exactly the inputs of `fixer4d bench train-step`.

    project = write_nerfstudio_project(dir, cameras, images, points, colors)
    result = run_opensplat(binary, project, iters=30)   # OpenSplatResult

The project is nerfstudio format, which OpenSplat reads: ``transforms.json`` (per-frame
pinhole intrinsics and OpenGL-axes camera-to-world matrices), one PNG per camera at the
benchmark's size, and a binary PLY of the initial points with colours. OpenSplat is run on its
CPU backend (``--cpu``) at full size (``-d 1 --num-downscales 0``), with refinement held off past
the run so that every iteration does the same work as ours: render one image, L1 + 0.2 D-SSIM,
backward, Adam. How refinement is held off depends on the version, read from its ``--help``:
up to 1.1.x ``--warmup-length`` (refine only after that step); from 1.2.0 (the WebODM/OpenSplat
line) ``--densify-from`` past the run and ``--densify-until`` past it too, because 1.2.0 steps
Adam on every iteration only until densify-until (after it, every 32nd or 64th). Seconds per
iteration are taken from the wall-clock times at which its "Step k" progress lines appear
(startup, image loading and the final PLY write excluded); if it prints none, from the whole run
(then marked as including startup). CPU seconds per iteration (all its threads) come the same
way from its /proc/PID/stat user + system time read at each step line (Linux); where that cannot
be read, from the whole run's RUSAGE_CHILDREN delta (marked so). The whole run's CPU seconds are
kept too.

Reference figures of another program are only ever *cited* next to our own (OPENSPLAT_CITED),
with their date and conditions; nothing divides by them.
"""
from __future__ import annotations

import json
import os
import re
import resource
import shutil
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fixer4d.errors import InputError

# The last side-by-side measurement (docs/render.md at commit 9fd7044, "OpenSplat side by side, measured"):
# 2026-11-24 (with the fused loss, parallel binning and fused Adam), `fixer4d bench train-step
# --opensplat ... --repeats 3` (10 timed iterations of fixer4d, 60 of OpenSplat) on the idle
# 2-core machine (nothing else running; the 1-minute load 0.6-1.9 is the benchmark's own two
# busy cores), the two programs taking turns, medians of 3 runs each; same 5 Panoptic cameras,
# random points, sizes and loss, one image per iteration; OpenSplat 1.2.0
# (github.com/WebODM/OpenSplat bd0400d, the newest line) built from source with
# -DGPU_RUNTIME=CPU -DCMAKE_BUILD_TYPE=Release. Wall and CPU seconds (all threads) per
# iteration, keyed by (Gaussians, width, height). Cited in tables when no binary is given, never
# used as a divisor. (Earlier side-by-side figures: that page too; the bench's own: docs/scale.md.)
OPENSPLAT_CITED = {
    "source": "2026-11-24, idle 2-core machine, alternating, medians of 3; "
              "OpenSplat 1.2.0 (WebODM/OpenSplat bd0400d) CPU build",
    "opensplat_s_per_iter": {(30_000, 320, 180): 0.323, (100_000, 320, 180): 0.470,
                             (30_000, 640, 360): 1.185, (100_000, 640, 360): 1.513},
    "fixer4d_s_per_iter_then": {(30_000, 320, 180): 0.068, (100_000, 320, 180): 0.121,
                                (30_000, 640, 360): 0.186, (100_000, 640, 360): 0.271},
    "opensplat_cpu_s_per_iter": {(30_000, 320, 180): 0.592, (100_000, 320, 180): 0.852,
                                 (30_000, 640, 360): 2.268, (100_000, 640, 360): 2.866},
    "fixer4d_cpu_s_per_iter_then": {(30_000, 320, 180): 0.119, (100_000, 320, 180): 0.203,
                                    (30_000, 640, 360): 0.345, (100_000, 640, 360): 0.485},
}
# Step lines OpenSplat prints while training ("Step 10: 0.2345 (0%)"); at least two distinct
# steps are needed to time iterations without startup.
_STEP_RE = re.compile(r"\bStep\s+(\d+)\b")
# OpenSplat densifies only after this many steps; set past the run so no step refines
_NO_REFINE_MARGIN = 10
# The option that holds refinement off, by OpenSplat line: 1.0-1.1.x, then 1.2.0 (WebODM/OpenSplat)
REFINE_FLAGS = {"warmup-length": ("--warmup-length",), "densify-from": ("--densify-from", "--densify-until")}


@dataclass
class OpenSplatResult:
    """One OpenSplat run: seconds per iteration, how it was timed, and the command."""

    s_per_iter: float
    timing: str  # "step lines k0..k1" or "whole run incl. startup"
    iters: int
    wall_s: float
    command: list[str]
    cpu_s_per_iter: float | None = None  # CPU seconds (user + system, all threads) per iteration
    cpu_timing: str = "not measured"
    cpu_s_total: float | None = None  # the whole run's CPU seconds (RUSAGE_CHILDREN delta)


def _write_ply(path: Path, points: np.ndarray, colors: np.ndarray) -> None:
    """Binary little-endian PLY: float x, y, z and uchar red, green, blue per vertex."""
    n = len(points)
    rgb8 = np.clip(np.round(np.asarray(colors, np.float64) * 255.0), 0, 255).astype(np.uint8)
    rec = np.empty(n, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("red", "u1"), ("green", "u1"),
                             ("blue", "u1")])
    rec["x"], rec["y"], rec["z"] = (np.asarray(points, np.float32)[:, k] for k in range(3))
    rec["red"], rec["green"], rec["blue"] = rgb8[:, 0], rgb8[:, 1], rgb8[:, 2]
    header = ("ply\nformat binary_little_endian 1.0\n"
              f"element vertex {n}\n"
              "property float x\nproperty float y\nproperty float z\n"
              "property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n")
    with open(path, "wb") as fh:
        fh.write(header.encode("ascii"))
        fh.write(rec.tobytes())


def write_nerfstudio_project(out_dir: str | os.PathLike, cameras, images, points: np.ndarray,
                             colors: np.ndarray) -> Path:
    """Write a nerfstudio project OpenSplat can train on; returns its folder.

    cameras: fixer4d Cameras (OpenCV axes); images: one (H, W, 3) float [0, 1] image per camera,
    at that camera's size; points: (N, 3) world positions; colors: (N, 3) in [0, 1]. Frames are
    named so that OpenSplat's sort by file name keeps the cameras' order.
    """
    from PIL import Image

    out = Path(out_dir)
    if len(cameras) != len(images):
        raise InputError(f"OpenSplat project: {len(cameras)} cameras but {len(images)} images")
    (out / "images").mkdir(parents=True, exist_ok=True)
    frames = []
    for i, (cam, img) in enumerate(zip(cameras, images)):
        img = np.asarray(img)
        if img.shape != (cam.height, cam.width, 3):
            raise InputError(f"OpenSplat project: image {i} has shape {img.shape}, camera {cam.name!r} is "
                             f"{cam.width}x{cam.height}")
        name = f"images/frame_{i:05d}.png"
        Image.fromarray(np.clip(np.round(img * 255.0), 0, 255).astype(np.uint8)).save(out / name)
        frames.append({"file_path": name, "w": int(cam.width), "h": int(cam.height),
                       "fl_x": float(cam.fx), "fl_y": float(cam.fy), "cx": float(cam.cx), "cy": float(cam.cy),
                       "k1": 0.0, "k2": 0.0, "p1": 0.0, "p2": 0.0,
                       "transform_matrix": cam.c2w_opengl().tolist()})
    _write_ply(out / "points.ply", points, colors)
    with open(out / "transforms.json", "w") as fh:
        json.dump({"camera_model": "OPENCV", "ply_file_path": "points.ply", "frames": frames}, fh, indent=1)
    return out


def opensplat_command(binary: str | os.PathLike, project: Path, iters: int, output: Path,
                      refine: str = "warmup-length") -> list[str]:
    """The OpenSplat command line for a benchmark run of ``iters`` iterations; ``refine`` names
    the option line that holds refinement off (a key of REFINE_FLAGS, from ``opensplat_info``)."""
    hold = [x for flag in REFINE_FLAGS[refine] for x in (flag, str(iters + _NO_REFINE_MARGIN))]
    return [str(binary), str(project), "--cpu", "-n", str(iters), "-d", "1", "--num-downscales", "0",
            *hold, "-o", str(output)]


def opensplat_info(binary: str | os.PathLike) -> dict:
    """{"version", "refine"} of an OpenSplat binary, from ``--version`` and ``--help``; InputError
    when its help names neither way of holding refinement off (not an OpenSplat we know)."""
    exe = resolve_binary(binary)

    def ask(flag: str) -> str:
        try:
            res = subprocess.run([exe, flag], capture_output=True, text=True, timeout=60)
        except (OSError, subprocess.TimeoutExpired) as e:
            raise InputError(f"--opensplat {binary}: `{flag}` failed: {e}") from e
        return res.stdout + res.stderr

    help_text = ask("--help")
    found = [k for k in REFINE_FLAGS if f"--{k}" in help_text]
    if not found:
        raise InputError(f"--opensplat {binary}: its --help names none of "
                         f"{', '.join('--' + k for k in REFINE_FLAGS)}; is it OpenSplat?\n{help_text[-2000:]}")
    version = ask("--version").strip().splitlines()
    return {"version": version[-1] if version else "unknown", "refine": found[0]}


def seconds_per_iter(events: list[tuple[float, int]], wall_s: float, iters: int) -> tuple[float, str]:
    """(seconds per iteration, how timed) from (time, step) progress events of one run; the
    times may be wall-clock or CPU seconds (then wall_s is the whole run's CPU seconds)."""
    steps: dict[int, float] = {}
    for t, k in events:
        steps.setdefault(k, t)  # first time each step was reported
    if len(steps) >= 2:
        k0, k1 = min(steps), max(steps)
        return (steps[k1] - steps[k0]) / (k1 - k0), f"step lines {k0}..{k1}"
    return wall_s / max(iters, 1), "whole run incl. startup"


def process_cpu_s(pid: int) -> float | None:
    """User + system CPU seconds so far of a running process (all its threads), from
    /proc/PID/stat; None where that cannot be read (not Linux, process gone)."""
    try:
        with open(f"/proc/{pid}/stat") as fh:
            stat = fh.read()
    except OSError:
        return None
    fields = stat[stat.rindex(")") + 2:].split()  # after "pid (comm) "; fields[0] is the state
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")  # utime, stime


def _children_cpu_s() -> float:
    ru = resource.getrusage(resource.RUSAGE_CHILDREN)
    return ru.ru_utime + ru.ru_stime


def resolve_binary(binary: str | os.PathLike) -> str:
    """The path of an executable OpenSplat (a file path, or a name on PATH); InputError if none."""
    exe = str(binary) if Path(binary).is_file() else shutil.which(str(binary))
    if exe is None or not os.access(exe, os.X_OK):
        raise InputError(f"--opensplat {binary}: not an executable file; build OpenSplat "
                         "(https://github.com/pierotofy/OpenSplat, -DGPU_RUNTIME=CPU) and pass its path")
    return exe


def run_opensplat(binary: str | os.PathLike, project: Path, iters: int, timeout_s: float | None = None,
                  refine: str | None = None) -> OpenSplatResult:
    """Run OpenSplat on ``project`` for ``iters`` iterations and time its iterations; ``refine``
    as in opensplat_command (None: asked of the binary)."""
    exe = resolve_binary(binary)
    refine = refine or opensplat_info(exe)["refine"]
    cmd = opensplat_command(exe, project, iters, project / "opensplat_out.ply", refine=refine)
    events: list[tuple[float, int]] = []
    cpu_events: list[tuple[float, int]] = []
    c0 = _children_cpu_s()
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, bufsize=1)
    tail: list[str] = []
    assert proc.stdout is not None
    for line in proc.stdout:
        now = time.perf_counter()
        m = _STEP_RE.search(line)
        if m:
            events.append((now, int(m.group(1))))
            cpu = process_cpu_s(proc.pid)
            if cpu is not None:
                cpu_events.append((cpu, int(m.group(1))))
        tail = (tail + [line.rstrip()])[-20:]
        if timeout_s is not None and now - t0 > timeout_s:
            proc.kill()
            break
    rc = proc.wait()
    wall = time.perf_counter() - t0
    cpu_total = _children_cpu_s() - c0
    if rc != 0:
        raise InputError(f"OpenSplat exited with status {rc}: {' '.join(cmd)}\n" + "\n".join(tail))
    s_it, how = seconds_per_iter(events, wall, iters)
    cpu_it, cpu_how = seconds_per_iter(cpu_events, cpu_total, iters)
    return OpenSplatResult(s_per_iter=s_it, timing=how, iters=iters, wall_s=wall, command=cmd,
                           cpu_s_per_iter=cpu_it, cpu_timing=cpu_how, cpu_s_total=cpu_total)
