"""`fixer4d bench viewer`: the splat renderer's frame time and the UI's frame time while
training runs.

Part 1, per Gaussian count (default 10k, 100k, 1M) at 1280x720: sort (depth order at the
current time, the worker thread's job, timed here inline), upload (the sorted index buffer),
draw (instanced splats until the GPU finishes), median over repeats with the camera moving
a little each repeat so every frame re-sorts. The one-time parameter-texture upload is
reported separately. Gaussians lie on a unit sphere (a surface, like a trained model's) with a
density-matched size (std = SCALE_PER_SPACING x the mean spacing on the surface), so the
overdraw per pixel stays similar across counts.

Part 2: the whole viewer (imgui panels + 3D view) headless on the "tiny" synthetic scene, the
median UI frame time with training idle and while ``Trainer.step()`` runs in its thread.

Prints a table and writes JSON (default benchmarks/results/viewer.json). On this machine the
GL is Mesa llvmpipe (software rasterizer on the CPU): the numbers say so in "renderer".
"""
from __future__ import annotations

import argparse
import platform
import statistics
import time
from pathlib import Path

import numpy as np

from fixer4d.atomic import write_json

DEFAULT_COUNTS = (10_000, 100_000, 1_000_000)
# Gaussian std as a fraction of the mean spacing sqrt(4 pi / N) on the unit sphere: neighbours
# overlap like a trained model's, so the fragments per pixel do not explode or vanish with N.
SCALE_PER_SPACING = 0.5
# The UI loop is paced like a 60 Hz vsync'd window (the app swaps with swap_interval 1): the
# rest of each frame period is left to training.
FRAME_PERIOD_S = 1.0 / 60.0


def synthetic_gaussians(n: int, seed: int = 0):
    from app.gaussians import GaussianArrays

    rng = np.random.default_rng(seed)
    std = SCALE_PER_SPACING * np.sqrt(4.0 * np.pi / n)
    means = rng.normal(size=(n, 3))
    means /= np.linalg.norm(means, axis=1, keepdims=True)
    return GaussianArrays(means=means, log_scales=np.log(std * rng.uniform(0.5, 1.5, (n, 3))),
                          quats=rng.normal(size=(n, 4)), opacity_logits=rng.normal(0.0, 1.0, n),
                          colors=rng.normal(0.0, 1.0, (n, 3)), t_center=rng.uniform(0, 1, n),
                          t_log_scale=np.full(n, np.log(0.5)), motion=rng.normal(0.0, 0.1, (n, 9)),
                          omega=rng.normal(0.0, 0.1, (n, 4)), dynamic=rng.uniform(size=n) < 0.5)


def bench_splats(ctx, counts, width: int, height: int, repeats: int) -> list[dict]:
    from app.gl.splats import SplatRenderer, depth_order
    from fixer4d.geometry.camera import Camera

    rows = []
    for n in counts:
        g = synthetic_gaussians(n)
        r = SplatRenderer(ctx)
        tic = time.perf_counter()
        r.set_gaussians(g)
        ctx.finish()
        texture_ms = 1e3 * (time.perf_counter() - tic)
        sort_ms, upload_ms, draw_ms, instances = [], [], [], 0
        for k in range(repeats + 1):  # the first is a warm-up (shader compile, allocation)
            cam = Camera.look_at([0.3 * np.sin(k), 0.2, -3.2], [0, 0, 0], width=width, height=height)
            t = 0.3 + 0.01 * k
            tic = time.perf_counter()
            order = depth_order(g, cam.w2c, t)
            s_ms = 1e3 * (time.perf_counter() - tic)
            tic = time.perf_counter()
            r.upload_order(order, cam, t)
            u_ms = 1e3 * (time.perf_counter() - tic)
            stats = r.render(cam, t)
            if k:
                sort_ms.append(s_ms)
                upload_ms.append(u_ms)
                draw_ms.append(stats.draw_ms)
                instances = stats.instances
        r.release()
        row = {"gaussians": n, "drawn": instances, "sort_ms": statistics.median(sort_ms),
               "upload_ms": statistics.median(upload_ms), "draw_ms": statistics.median(draw_ms),
               "texture_upload_ms_once": texture_ms}
        row["frame_ms"] = row["sort_ms"] + row["upload_ms"] + row["draw_ms"]
        rows.append(row)
        print(f"  {n:>9,d} Gaussians: sort {row['sort_ms']:8.1f}  upload {row['upload_ms']:6.1f}  "
              f"draw {row['draw_ms']:8.1f}  frame {row['frame_ms']:8.1f} ms", flush=True)
    return rows


def bench_ui(ctx, frames: int, iterations: int) -> dict:
    from app.main import initial_state, live_trainer
    from app.session import TrainingSession
    from app.viewer import Viewer, ViewerSource
    from fixer4d.scene import load_scene

    scene = load_scene("tiny")
    training = TrainingSession(lambda: live_trainer(scene, iterations, "sparse", 2), publish_every=10)
    src = ViewerSource(scene=scene, label="bench", training=training)
    state = initial_state(src, None)
    viewer = Viewer(ctx, state, src)
    fbo = ctx.simple_framebuffer((1280, 720))
    try:
        training.start()
        deadline = time.monotonic() + 300
        while state.gaussians is None and time.monotonic() < deadline:
            viewer.frame(1 / 60, fbo)
            time.sleep(0.05)
        if state.gaussians is None:
            raise RuntimeError(f"training did not start: {training.error or training.state}")
        training.pause()
        time.sleep(0.2)
        for _ in range(5):
            viewer.frame(1 / 60, fbo)
        idle = []
        for _ in range(frames):
            tic_frame = time.perf_counter()
            viewer.frame(FRAME_PERIOD_S, fbo)
            idle.append(viewer.frame_ms)
            time.sleep(max(0.0, FRAME_PERIOD_S - (time.perf_counter() - tic_frame)))
        step0, tic = training.step, time.perf_counter()
        training.resume()
        busy = []
        for _ in range(frames):
            tic_frame = time.perf_counter()
            viewer.frame(FRAME_PERIOD_S, fbo)
            busy.append(viewer.frame_ms)
            time.sleep(max(0.0, FRAME_PERIOD_S - (time.perf_counter() - tic_frame)))
        steps_per_s = (training.step - step0) / (time.perf_counter() - tic)
    finally:
        viewer.close()
    out = {"scene": "tiny", "window": [1280, 720], "gaussians": state.gaussians.n,
           "ui_frame_ms_idle": statistics.median(idle), "ui_frame_ms_training": statistics.median(busy),
           "ui_frame_ms_training_p90": float(np.percentile(busy, 90)), "training_steps_per_s": steps_per_s}
    print(f"  UI frame (1280x720 window, {out['gaussians']} Gaussians, paced at 60 Hz): idle {out['ui_frame_ms_idle']:.1f} ms, "
          f"training {out['ui_frame_ms_training']:.1f} ms (p90 {out['ui_frame_ms_training_p90']:.1f}), "
          f"{steps_per_s:.1f} training steps/s meanwhile", flush=True)
    return out


def main(argv: list[str] | None = None) -> int:
    import moderngl

    p = argparse.ArgumentParser(prog="fixer4d bench viewer", description=__doc__.splitlines()[0])
    p.add_argument("--counts", default=",".join(str(c) for c in DEFAULT_COUNTS), help="Gaussian counts")
    p.add_argument("--size", default="1280x720")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--ui-frames", type=int, default=40)
    p.add_argument("--ui-iterations", type=int, default=2000)
    p.add_argument("--out", default="benchmarks/results/viewer.json")
    args = p.parse_args(argv)
    width, height = (int(v) for v in args.size.lower().split("x"))
    ctx = moderngl.create_standalone_context(backend="egl", require=330)
    renderer = f"{ctx.info['GL_RENDERER']} / {ctx.info['GL_VERSION']}"
    print(f"viewer benchmark on {renderer} ({'software, CPU' if 'llvmpipe' in renderer else 'GPU'}), "
          f"{width}x{height}", flush=True)
    splats = bench_splats(ctx, [int(c) for c in args.counts.split(",")], width, height, args.repeats)
    ui = bench_ui(ctx, args.ui_frames, args.ui_iterations)
    result = {"benchmark": "viewer", "renderer": renderer, "size": [width, height], "machine": platform.machine(),
              "splats": splats, "ui": ui}
    write_json(Path(args.out), result)
    print(f"wrote {args.out}")
    return 0


def demo_surface_gaussians(scene, target: int = 30_000, frame: int = 0):
    """A stand-in for the demo's trained model when no run folder is given: about ``target``
    static Gaussians on the scene's true surfaces (every k-th pixel of each train view at
    ``frame`` back-projected with its depth, coloured by the pixel, sized to the sample
    spacing), so the splat count, sizes and screen coverage are those of a trained model."""
    from app.gaussians import GaussianArrays
    from fixer4d.model.spacetime import SH_C0

    pixels = sum(scene.cameras[i].width * scene.cameras[i].height for i in scene.train_ids)
    stride = max(1, int(round(np.sqrt(pixels / target))))
    pts, cols, sizes = [], [], []
    for i in scene.train_ids:
        cam = scene.cameras[i]
        depth = scene.depth(frame, i)
        ok = np.isfinite(depth)
        xyz = cam.backproject_depth(np.where(ok, depth, 0.0))
        sel = np.zeros(depth.shape, bool)
        sel[::stride, ::stride] = True
        sel &= ok
        pts.append(xyz[sel])
        cols.append(scene.frame(frame, i)[sel])
        sizes.append(depth[sel] * stride / cam.fx / 2.0)
    p, c, s = np.concatenate(pts), np.concatenate(cols), np.concatenate(sizes)
    n = p.shape[0]
    return GaussianArrays(means=p, log_scales=np.log(np.repeat(s[:, None], 3, 1)), quats=np.tile([1.0, 0, 0, 0], (n, 1)),
                          opacity_logits=np.full(n, 3.0), colors=(c - 0.5) / SH_C0, t_center=np.zeros(n),
                          t_log_scale=np.zeros(n), motion=np.zeros((n, 9)), omega=np.zeros((n, 4)),
                          dynamic=np.zeros(n, bool), model_config={"motion_degree": 3, "rotation_velocity": True,
                                                                   "temporal_opacity": True, "sh_degree": 0})


def bench_orbit(ctx, model: str | None, frames: int, window: tuple[int, int]) -> dict:
    """The whole viewer (panels + 3D view) on the demo while the mouse orbits the camera (a
    steady left-drag fed through imgui's io, one step per frame): frames per second with
    adaptive resolution and with it off, each frame finished on the GPU before the next."""
    from imgui_bundle import imgui

    from app.main import initial_state, open_source
    from app.viewer import Viewer, ViewerSource
    from fixer4d.scene import load_scene

    if model:
        src, g, _ = open_source(model)
        label = model
    else:
        scene = load_scene("demo")
        g = demo_surface_gaussians(scene)
        src = ViewerSource(scene=scene, label="demo (surface model)")
        label = f"demo scene surfaces, {g.n} static Gaussians (no run folder given)"
    fbo = ctx.simple_framebuffer(window)
    out = {"model": label, "gaussians": int(g.n), "window": list(window)}
    for adaptive in (True, False):
        state = initial_state(src, g)
        state.show_frusta = state.show_trajectories = False
        viewer = Viewer(ctx, state, src)
        viewer.adaptive.enabled = adaptive
        try:
            for _ in range(3):  # layout, first sort, shader warm-up
                viewer.frame(1 / 60, fbo)
            x0, y0, w, h = viewer.viewport_rect
            io = imgui.get_io()
            io.add_mouse_pos_event(x0 + w / 2, y0 + h / 2)
            viewer.frame(1 / 60, fbo)
            io.add_mouse_button_event(0, True)
            viewer.frame(1 / 60, fbo)
            times, scales = [], []
            for k in range(frames):
                io.add_mouse_pos_event(x0 + w / 2 + 4.0 * (k + 1), y0 + h / 2)
                tic = time.perf_counter()
                viewer.frame(1 / 60, fbo)
                ctx.finish()
                times.append(time.perf_counter() - tic)
                scales.append(viewer.adaptive.scale)
            io.add_mouse_button_event(0, False)
            viewer.frame(1 / 60, fbo)
        finally:
            viewer.close()
        key = "adaptive" if adaptive else "full_resolution"
        out[f"orbit_fps_{key}"] = len(times) / sum(times)
        out[f"orbit_frame_ms_{key}_median"] = 1e3 * statistics.median(times)
        if adaptive:
            out["orbit_render_scale_median"] = statistics.median(scales)
    out["orbit_fps"] = out["orbit_fps_adaptive"]
    print(f"  orbit ({label}, {window[0]}x{window[1]} window): {out['orbit_fps_adaptive']:.1f} fps adaptive "
          f"(median scale {out['orbit_render_scale_median']:.2f}), {out['orbit_fps_full_resolution']:.1f} fps "
          f"at full resolution", flush=True)
    return out
