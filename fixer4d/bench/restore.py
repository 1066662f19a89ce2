"""`fixer4d bench restore`: seconds per restored clip and the restorer's gain over a degraded render.

The benchmark carries its own analytic ground truth (``AnalyticScene``: a textured ground,
three textured spheres and a textured dome, ray-cast exactly), so it runs without any other
stage: four rig cameras look at the scene; a clip of F frames interpolates between the two
endpoint cameras; the "render" the restorer gets is the true clip blurred and punched with holes
(alpha 0, depth 0); the references are the true endpoint images with their true depth. The
restorer's output is scored against the true clip (PSNR, all frames).

Rows: the two clip sizes the brief asks for (200x150 and 320x240, F=16), each timed over a few
repeats, plus accuracy variants at 200x150 (extra views on/off, temporal smoothing on/off,
noisy model depth instead of the true one).
"""
from __future__ import annotations

import argparse
import dataclasses
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from fixer4d.bench import positive_int
from fixer4d.geometry.camera import Camera

DEFAULT_OUT = "benchmarks/results/restore.json"

# Pixel-space blur (std dev) of the degraded render: what an under-fitted Gaussian model looks
# like at a novel view (fine texture gone, shapes intact).
DEGRADE_BLUR_PX = 2.0
# Fraction of the clip's area punched out as holes (alpha 0) in the degraded render.
DEGRADE_HOLE_FRACTION = 0.12
# Relative std dev of the depth error of the "noisy model depth" variant: a smooth function of the
# world point, so the error is consistent across views and frames like a model's geometry error.
NOISY_DEPTH_REL = 0.02
# Rendering supersampling factor of the analytic ground truth (anti-aliased images, like a camera).
SUPERSAMPLE = 2
# The point every rig and trajectory camera looks at (the middle of the spheres).
TARGET = (0.0, 0.45, 0.0)


@dataclass(frozen=True)
class _Sphere:
    center: tuple[float, float, float]
    radius: float
    color_a: tuple[float, float, float]
    color_b: tuple[float, float, float]
    stripes: float


class AnalyticScene:
    """Exact ray-cast images and z-depth of a fixed textured scene for any camera.

    World: y up, ground plane y = 0, spheres resting on it, everything inside a dome of radius
    ``DOME_RADIUS`` centred at the origin, so every ray hits something (finite depth everywhere).
    """

    DOME_RADIUS = 12.0
    SPHERES = (
        _Sphere((0.0, 0.6, 0.0), 0.6, (0.9, 0.3, 0.2), (1.0, 0.9, 0.4), 10.0),
        _Sphere((-0.9, 0.35, 0.7), 0.35, (0.2, 0.5, 0.9), (0.9, 0.95, 1.0), 7.0),
        _Sphere((0.9, 0.45, -0.6), 0.45, (0.2, 0.8, 0.3), (0.1, 0.2, 0.1), 12.0),
    )

    def render(self, camera: Camera, supersample: int = SUPERSAMPLE) -> tuple[np.ndarray, np.ndarray]:
        """rgb (H, W, 3) float32 in [0, 1] (anti-aliased by ``supersample``^2 samples per pixel)
        and z-depth (H, W) float32 (pixel-centre ray)."""
        _, depth = self._cast(camera)
        if supersample > 1:
            big = camera.resized(camera.width * supersample, camera.height * supersample)
            rgb_big, _ = self._cast(big)
            rgb = cv2.resize(rgb_big, (camera.width, camera.height), interpolation=cv2.INTER_AREA)
        else:
            rgb, _ = self._cast(camera)
        return rgb.astype(np.float32), depth.astype(np.float32)

    def _cast(self, camera: Camera) -> tuple[np.ndarray, np.ndarray]:
        d = camera.ray_directions().reshape(-1, 3)  # camera-frame z = 1, so t is the z-depth
        o = camera.center
        n = d.shape[0]
        best_t = np.full(n, np.inf)
        rgb = np.zeros((n, 3))
        # dome (seen from inside: the far root)
        a = np.sum(d * d, axis=1)
        b = 2.0 * d @ o
        c = float(o @ o) - self.DOME_RADIUS ** 2
        t_dome = (-b + np.sqrt(np.maximum(b * b - 4 * a * c, 0.0))) / (2 * a)
        p = o + t_dome[:, None] * d
        theta = np.arctan2(p[:, 2], p[:, 0])
        stripes = 0.5 + 0.5 * np.sin(18.0 * theta) * np.cos(2.5 * p[:, 1])
        rgb[:] = np.stack([0.35 + 0.3 * stripes, 0.45 + 0.2 * stripes, 0.7 - 0.2 * stripes], 1)
        best_t[:] = t_dome
        # ground
        with np.errstate(divide="ignore", invalid="ignore"):
            t_g = -o[1] / d[:, 1]
        hit = (t_g > 0) & (t_g < best_t)
        p = o + t_g[hit, None] * d[hit]
        checker = (np.floor(p[:, 0] / 0.3) + np.floor(p[:, 2] / 0.3)) % 2
        wave = 0.5 + 0.5 * np.sin(9.0 * p[:, 0] + 4.0 * np.sin(3.0 * p[:, 2]))
        rgb[hit] = np.stack([0.25 + 0.45 * checker + 0.2 * wave, 0.25 + 0.35 * checker, 0.2 + 0.3 * wave], 1)
        best_t[hit] = t_g[hit]
        # spheres
        for s in self.SPHERES:
            oc = o - np.asarray(s.center)
            b = 2.0 * d @ oc
            c = float(oc @ oc) - s.radius ** 2
            disc = b * b - 4 * a * c
            with np.errstate(invalid="ignore"):
                t_s = (-b - np.sqrt(disc)) / (2 * a)
            hit = (disc > 0) & (t_s > 0) & (t_s < best_t)
            q = (o + t_s[hit, None] * d[hit] - np.asarray(s.center)) / s.radius
            lon = np.arctan2(q[:, 2], q[:, 0])
            pattern = 0.5 + 0.5 * np.sign(np.sin(s.stripes * lon) * np.sin(s.stripes * 0.7 * np.arcsin(np.clip(q[:, 1], -1, 1))))
            shade = 0.6 + 0.4 * np.clip(q[:, 1] * 0.5 + 0.5, 0, 1)
            col = np.asarray(s.color_a) * (1 - pattern[:, None]) + np.asarray(s.color_b) * pattern[:, None]
            rgb[hit] = col * shade[:, None]
            best_t[hit] = t_s[hit]
        return np.clip(rgb, 0, 1).reshape(camera.height, camera.width, 3), best_t.reshape(camera.height, camera.width)


def rig_cameras(width: int, height: int) -> list[Camera]:
    """Four cameras on an arc of radius 4 at 1.2 height, 30 degrees apart, looking at the spheres."""
    cams = []
    for i, deg in enumerate((-45.0, -15.0, 15.0, 45.0)):
        ang = np.radians(deg)
        eye = (4.0 * np.sin(ang), 1.2, 4.0 * np.cos(ang))
        K = Camera.intrinsics_from_fov(np.radians(45.0), width, height)
        cams.append(Camera.look_at(eye, TARGET, up=(0.0, 1.0, 0.0), K=K, width=width, height=height, name=f"cam{i:02d}"))
    return cams


def trajectory_cameras(cam_i: Camera, cam_j: Camera, num_frames: int) -> list[Camera]:
    """F cameras from cam_i to cam_j: centres interpolated on the rig's arc (same radius and
    height), looking at the rig's target, so every frame is a plausible held-out viewpoint."""
    ci, cj = cam_i.center, cam_j.center
    ai, aj = np.arctan2(ci[0], ci[2]), np.arctan2(cj[0], cj[2])
    radius = float(np.hypot(ci[0], ci[2]))
    cams = []
    for k, s in enumerate(np.linspace(0.0, 1.0, num_frames)):
        ang = (1 - s) * ai + s * aj
        eye = (radius * np.sin(ang), (1 - s) * ci[1] + s * cj[1], radius * np.cos(ang))
        cams.append(Camera.look_at(eye, TARGET, up=(0.0, 1.0, 0.0), K=cam_i.K, width=cam_i.width,
                                   height=cam_i.height, name=f"traj{k:02d}"))
    return cams


def degrade(rgb: np.ndarray, depth: np.ndarray, rng: np.random.Generator,
            hole_fraction: float = DEGRADE_HOLE_FRACTION,
            blur_px: float = DEGRADE_BLUR_PX) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A fake under-fitted render of a true frame: blurred, with elliptical holes (alpha 0,
    rgb 0, depth 0). Returns rgb (H, W, 3), depth (H, W), alpha (H, W), float32."""
    H, W = depth.shape
    blurred = cv2.GaussianBlur(rgb, (0, 0), blur_px) if blur_px > 0 else rgb.copy()
    holes = np.zeros((H, W), np.uint8)
    while holes.mean() < hole_fraction:  # whole ellipses until the area is reached
        center = (int(rng.integers(0, W)), int(rng.integers(0, H)))
        axes = (int(rng.integers(W // 20, W // 7)), int(rng.integers(H // 20, H // 7)))
        cv2.ellipse(holes, center, axes, float(rng.uniform(0, 180)), 0, 360, 1, -1)
    alpha = 1.0 - holes.astype(np.float32)
    return (blurred * alpha[..., None]).astype(np.float32), (depth * alpha).astype(np.float32), alpha


def noisy_depth(depth: np.ndarray, camera: Camera, rel: float = NOISY_DEPTH_REL) -> np.ndarray:
    """A model-like wrong depth: true depth x (1 + rel * n(X)), with n a smooth field of the world
    point X (std ~1, wavelength ~1 unit), so the error is the same surface error in every view and
    frame, like a model's geometry error (not per-pixel noise)."""
    from fixer4d.restore.reference_warp import backproject

    finite = np.isfinite(depth)
    X = backproject(camera, np.where(finite, depth, 0.0).astype(np.float64))
    field = (np.sin(5.1 * X[..., 0] + 1.3) + np.sin(4.3 * X[..., 1] + 0.7 * X[..., 2] + 2.1)
             + np.sin(3.7 * X[..., 2] - 2.9 * X[..., 0] + 0.4)) / np.sqrt(1.5)
    return np.where(finite, depth * (1.0 + rel * field), depth).astype(np.float32)


def make_request(width: int = 200, height: int = 150, num_frames: int = 16, *, pair: tuple[int, int] = (0, 1),
                 seed: int = 0, depth_noise: float = 0.0, hole_fraction: float = DEGRADE_HOLE_FRACTION,
                 blur_px: float = DEGRADE_BLUR_PX, scene: AnalyticScene | None = None):
    """A RestoreRequest on the analytic scene plus the true clip.

    Returns (request, gt_rgb (F, H, W, 3)). The render is ``degrade``d truth; the references are
    the true images of the pair's cameras; the other two rig cameras are the extra views. With
    ``depth_noise`` > 0 every depth the restorer gets (novel and reference) is ``noisy_depth``;
    ``hole_fraction`` and ``blur_px`` set the degradation (``degrade``).
    """
    from fixer4d.restore.base import RestoreRequest

    scene = scene if scene is not None else AnalyticScene()
    rng = np.random.default_rng(seed)
    rig = rig_cameras(width, height)
    cams = trajectory_cameras(rig[pair[0]], rig[pair[1]], num_frames)
    gt_rgb, rgb, depth, alpha = [], [], [], []
    for cam in cams:
        g, d = scene.render(cam)
        if depth_noise > 0:
            d = noisy_depth(d, cam, depth_noise)
        r, dd, a = degrade(g, d, rng, hole_fraction, blur_px)
        gt_rgb.append(g)
        rgb.append(r)
        depth.append(dd)
        alpha.append(a)
    views = [scene.render(c) for c in rig]
    if depth_noise > 0:
        views = [(im, noisy_depth(d, c, depth_noise)) for (im, d), c in zip(views, rig)]
    extra = [i for i in range(len(rig)) if i not in pair]
    request = RestoreRequest(
        rgb=np.stack(rgb), depth=np.stack(depth), alpha=np.stack(alpha), cameras=cams, time=0.0, frame=0,
        ref_images=[views[i][0] for i in pair], ref_cameras=[rig[i] for i in pair],
        ref_depths=[views[i][1] for i in pair], ref_alphas=[np.ones((height, width), np.float32) for _ in pair],
        extra_images=[views[i][0] for i in extra], extra_cameras=[rig[i] for i in extra],
        extra_depths=[views[i][1] for i in extra],
        trajectory={"name": f"pair_{pair[0]}-{pair[1]}", "pair": list(pair), "amplitude": 0.0})
    return request, np.stack(gt_rgb)


def clip_psnr(pred: np.ndarray, gt: np.ndarray) -> float:
    """Mean over frames of per-frame PSNR (dB, ``fixer4d.eval.metrics.psnr`` capped at 120 dB)
    of (F, H, W, 3) images in [0, 1]."""
    from fixer4d.eval.metrics import psnr

    return float(np.mean([psnr(p, g, max_db=120.0) for p, g in zip(pred, gt)]))


def main(argv: list[str] | None = None) -> int:
    from fixer4d.atomic import write_json
    from fixer4d.restore.reference_warp import ReferenceWarpConfig, ReferenceWarpRestorer

    parser = argparse.ArgumentParser(prog="fixer4d bench restore", description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=DEFAULT_OUT, help=f"JSON output (default {DEFAULT_OUT})")
    parser.add_argument("--frames", type=positive_int, default=16, help="frames per clip (default 16)")
    parser.add_argument("--repeats", type=positive_int, default=3, help="timed runs per size; the median is reported")
    args = parser.parse_args(argv)

    rows = []
    base = ReferenceWarpConfig()
    variants = [("default", base, 0.0), ("no extra views", dataclasses.replace(base, use_extra_views=False), 0.0),
                ("no temporal smoothing", dataclasses.replace(base, temporal_radius=0), 0.0),
                ("noisy model depth", base, NOISY_DEPTH_REL),
                ("noisy depth, no extra views", dataclasses.replace(base, use_extra_views=False), NOISY_DEPTH_REL)]
    for width, height in ((200, 150), (320, 240)):
        for name, cfg, noise in variants if (width, height) == (200, 150) else variants[:1]:
            request, gt = make_request(width, height, args.frames, depth_noise=noise)
            restorer = ReferenceWarpRestorer(cfg)
            times, cpu = [], []
            for _ in range(max(1, args.repeats)):
                t0, c0 = time.perf_counter(), time.process_time()
                result = restorer.restore(request)
                times.append(time.perf_counter() - t0)
                cpu.append(time.process_time() - c0)
            rows.append({"size": f"{width}x{height}", "frames": args.frames, "variant": name,
                         "seconds_per_clip": float(np.median(times)), "cpu_seconds_per_clip": float(np.median(cpu)),
                         "psnr_render": clip_psnr(request.rgb, gt), "psnr_restored": clip_psnr(result.rgb, gt),
                         "mean_confidence": float(result.frame_confidence.mean())})
    print(f"{'size':>8} {'F':>3} {'variant':<28} {'s/clip':>7} {'cpu s':>6} {'PSNR render':>12} {'PSNR restored':>14} "
          f"{'conf':>5}")
    for r in rows:
        print(f"{r['size']:>8} {r['frames']:>3} {r['variant']:<28} {r['seconds_per_clip']:7.3f} {r['cpu_seconds_per_clip']:6.2f} "
              f"{r['psnr_render']:12.2f} {r['psnr_restored']:14.2f} {r['mean_confidence']:5.2f}")
    out = Path(args.out)
    import os

    write_json(out, {"benchmark": "restore", "restorer": ReferenceWarpRestorer.name, "rows": rows,
                     "load_average": list(os.getloadavg()), "cpu_count": os.cpu_count(),
                     "settings": dataclasses.asdict(base)})
    print(f"wrote {out}")
    return 0
