"""`fixer4d bench viewer`: the splat renderer's frame time, the whole viewer's frame rate while
orbiting the demo, and live training's speed in the viewer against the same training without it.

Part 1, per Gaussian count (default 10k, 100k, 1M) at 1280x720: sort (depth order at the
current time, the worker thread's job, timed here inline), upload (the sorted index buffer),
draw (preparation pass + instanced splats until the GPU finishes), median over repeats with
the camera moving a little each repeat so every frame re-sorts. The one-time parameter-texture
upload is reported separately. Gaussians lie on a unit sphere (a surface, like a trained
model's) with a density-matched size (std = SCALE_PER_SPACING x the mean spacing on the
surface), so the overdraw per pixel stays similar across counts.

Part 2 (``orbit_fps``): the whole viewer (panels + 3D view, 1440x900 window) on the demo with a
30k-splat model (``--model`` a run folder or model file; default the demo's true surfaces
back-projected, see ``demo_surface_gaussians``) while a left-drag orbits the camera every
frame: frames per second with adaptive resolution and level of detail (the viewer's default,
``orbit_fps``), with adaptive resolution only, and at full resolution, in alternating rounds.

Part 3 (``playback_fps_cached``): ``bench_playback``, the timeline playing with the camera at
rest: the time to fill the frame cache (each frame drawn once at full quality) and the frame
rate of playback from it.

Part 4 (``live_vs_pipeline_ratio``): ``bench_live``.

Prints a table and writes JSON (default benchmarks/results/viewer.json) with the load average,
since the machine may be shared. On this machine the GL is Mesa llvmpipe (software rasterizer
on the CPU): the numbers say so in "renderer".
"""
from __future__ import annotations

import argparse
import os
import platform
import statistics
import threading
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np

from app.gl.sync import finish as gl_finish
from fixer4d.atomic import write_json

DEFAULT_COUNTS = (10_000, 100_000, 1_000_000)
# Gaussian std as a fraction of the mean spacing sqrt(4 pi / N) on the unit sphere: neighbours
# overlap like a trained model's, so the fragments per pixel do not explode or vanish with N.
SCALE_PER_SPACING = 0.5
# Live-training steps left out of the timing (first renders, allocator warm-up).
LIVE_WARMUP_STEPS = 10
# Steps per turn when the plain loop and the viewer take turns (see bench_live).
LIVE_CHUNK_STEPS = 10


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


def bench_live(iterations: int, steps: int, warmup: int, scene_name: str = "demo", chunk: int = LIVE_CHUNK_STEPS) -> dict:
    """Live training in the viewer vs the same stage 1 without it. One setup function
    (``live_stage1_trainer``: the pipeline's stage-1 config, sparse init on 2 frames) builds two
    trainers: one stepped in a plain loop, as ``fixer4d run`` steps, one in the viewer's
    training thread while the whole UI draws headless (1440x900), paced like the window loop
    (app.main.pace_frame, nobody at the mouse). After ``warmup`` steps each, they take turns in
    chunks of ``chunk`` steps up to ``steps``, so a shared machine's changing load hits both
    alike. The plain loop steps in a thread started before the viewer's first frame, so it keeps
    the process's CPU priority when the viewer lowers its UI thread's (app.main.TRAINING_UI_NICE),
    as ``fixer4d run`` would have it. Returns steps/s of both and their ratio."""
    from app.session import live_stage1_trainer
    from fixer4d.scene import load_scene

    scene = load_scene(scene_name)

    def setup(report=lambda text: None):
        return live_stage1_trainer(scene, iterations, "sparse", 2, report)

    run = LiveTurns(scene, setup)
    tid = threading.get_native_id()
    ui_nice = os.getpriority(os.PRIO_PROCESS, tid)
    try:
        run.take_turns(steps, warmup, chunk)
        gaussians_viewer = 0 if run.viewer.state.gaussians is None else run.viewer.state.gaussians.n
        gaussians_live = int(run.training.trainer.model.num_gaussians)
    finally:
        run.close()
        _restore_ui_priority(tid, ui_nice)
    restored = os.getpriority(os.PRIO_PROCESS, tid) == ui_nice
    pipeline_rate, viewer_rate = run.plain_steps / run.plain_s, run.viewer_steps / run.viewer_s
    out = {"scene": scene_name, "iterations": iterations, "timed_steps": [warmup, steps], "chunk": chunk,
           "pipeline_steps_per_s": pipeline_rate, "viewer_steps_per_s": viewer_rate,
           "live_vs_pipeline_ratio": viewer_rate / pipeline_rate, "gaussians_pipeline": run.plain.model.num_gaussians,
           "gaussians_live": gaussians_live, "gaussians_viewer_shown": gaussians_viewer,
           "ui_frames_per_s_while_training": run.ui_frames / run.viewer_s, "ui_priority_restored_after": restored}
    print(f"  live training ({scene_name}, stage-1 config for {iterations} iterations, steps {warmup}..{steps} in "
          f"turns of {chunk}): {viewer_rate:.2f} steps/s in the viewer vs {pipeline_rate:.2f} without it "
          f"(ratio {out['live_vs_pipeline_ratio']:.2f}; UI {out['ui_frames_per_s_while_training']:.1f} frames/s)",
          flush=True)
    return out


class LiveTurns:
    """The two trainers of ``bench_live`` built by one ``setup``: ``plain``, stepped in a thread
    of its own, and the viewer's live ``training``, stepped while the viewer draws headless
    into a 1440x900 framebuffer. Counts the steps and seconds of each and the UI frames."""

    def __init__(self, scene: Any, setup: Callable[..., Any]) -> None:
        from concurrent.futures import ThreadPoolExecutor

        import moderngl

        from app.session import TrainingSession
        from app.sources import app_services, initial_state
        from app.viewer import Viewer, ViewerSource

        self.plain = setup()
        self.ctx = moderngl.create_standalone_context(backend="egl", require=330)
        self.training = TrainingSession(setup)
        src = ViewerSource(scene=scene, label="bench", training=self.training)
        self.viewer = Viewer(self.ctx, initial_state(src, None), src, services=app_services())
        self.fbo = self.ctx.simple_framebuffer((1440, 900))
        self.plain_s = self.viewer_s = 0.0
        self.plain_steps = self.viewer_steps = self.ui_frames = 0
        self.pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="plain-trainer")

    def take_turns(self, steps: int, warmup: int, chunk: int) -> None:
        """``warmup`` untimed steps each, then turns of ``chunk`` timed steps each up to ``steps``."""
        training = self.training
        self.pool.submit(self._plain_steps, warmup).result()
        # Turns of exactly n steps each: the live trainer pauses itself at the turn's last step
        # (TrainingSession.pause_at). Without that it ran on while the UI slept out its frame
        # period, densified ahead of the plain loop and was timed on a larger model (20k vs 3.3k
        # Gaussians at step 100 on the demo: the 0.56-0.67 "ratios" of earlier runs).
        training.pause_at = warmup
        training.start()
        self._ui_until(warmup)
        self._pause()
        while self.plain.step_count < steps:
            n = min(chunk, steps - self.plain.step_count)
            self.plain_s += self.pool.submit(self._plain_steps, n).result()
            self.plain_steps += n
            start_step, frames0 = training.step, self.ui_frames
            training.pause_at, training.paused_at_time = start_step + n, None
            tic = time.perf_counter()
            training.resume()
            self._ui_until(start_step + n)
            self._pause()
            self.viewer_s += (training.paused_at_time or time.perf_counter()) - tic
            self.viewer_steps += training.step - start_step
            if self.ui_frames == frames0:
                break

    def _ui_until(self, target: int) -> None:
        """Draw viewer frames, paced like the window loop, until live training reaches step ``target``."""
        from app.main import pace_frame

        training = self.training
        deadline = time.monotonic() + 1800
        while training.step < target and training.state not in ("failed", "done") and time.monotonic() < deadline:
            start = time.perf_counter()
            self.viewer.frame(1.0 / 10, self.fbo)
            gl_finish(self.ctx)  # as a window's swap: the wait releases the GIL
            self.ui_frames += 1
            pace_frame(self.viewer, start)
        if training.state == "failed":
            raise RuntimeError(f"live training failed: {training.error}")

    def _pause(self) -> None:
        """Pause live training and let a step already begun finish before the plain loop's turn."""
        self.training.pause()
        while self.training.stepping:
            time.sleep(0.005)

    def _plain_steps(self, n: int) -> float:
        """``n`` steps of the plain trainer; returns their seconds."""
        tic = time.perf_counter()
        for _ in range(n):
            self.plain.step()
        return time.perf_counter() - tic

    def close(self) -> None:
        self.pool.shutdown()
        self.viewer.close()
        self.ctx.release()


def _restore_ui_priority(tid: int, ui_nice: int) -> None:
    """Give thread ``tid`` its nice value ``ui_nice`` back: the next run's threads are started
    from it (raising a nice value needs privileges; without them the next run would start
    lowered, and bench_live's result says so)."""
    from app.main import _UI_THREADS_LOWERED

    _UI_THREADS_LOWERED.discard(tid)
    try:
        os.setpriority(os.PRIO_PROCESS, tid, ui_nice)
    except OSError:
        pass


def main(argv: list[str] | None = None) -> int:
    import moderngl

    p = argparse.ArgumentParser(prog="fixer4d bench viewer", description=__doc__.splitlines()[0])
    p.add_argument("--counts", default=",".join(str(c) for c in DEFAULT_COUNTS), help="Gaussian counts")
    p.add_argument("--size", default="1280x720")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--orbit-frames", type=int, default=30, help="frames of the orbit measurement")
    p.add_argument("--model", default=None, help="run folder or model file for the orbit (default: a 30k-splat "
                                                 "model of the demo's surfaces)")
    p.add_argument("--live-iterations", type=int, default=500, help="stage-1 iterations of the live-training config")
    p.add_argument("--live-steps", type=int, default=60, help="steps timed in each live-training run (after 10)")
    p.add_argument("--live-runs", type=int, default=1, help="live-training measurements (each reported)")
    p.add_argument("--parts", default="splats,orbit,playback,live",
                   help="which parts to run (comma-separated; a part left out is null in the JSON)")
    p.add_argument("--out", default="benchmarks/results/viewer.json")
    args = p.parse_args(argv)
    parts = {x.strip() for x in args.parts.split(",") if x.strip()}
    from app.main import configure_software_gl

    configure_software_gl()  # the viewer's GL settings (before the first context)
    width, height = (int(v) for v in args.size.lower().split("x"))
    ctx = moderngl.create_standalone_context(backend="egl", require=330)
    renderer = f"{ctx.info['GL_RENDERER']} / {ctx.info['GL_VERSION']}"
    print(f"viewer benchmark on {renderer} ({'software, CPU' if 'llvmpipe' in renderer else 'GPU'}), "
          f"{width}x{height}", flush=True)
    splats = bench_splats(ctx, [int(c) for c in args.counts.split(",")], width, height, args.repeats) \
        if "splats" in parts else None
    orbit = bench_orbit(ctx, args.model, args.orbit_frames, (1440, 900)) if "orbit" in parts else None
    playback = bench_playback(ctx, args.model, (width, height)) if "playback" in parts else None
    lives = [bench_live(args.live_iterations, args.live_steps, LIVE_WARMUP_STEPS) for _ in range(args.live_runs)] \
        if "live" in parts else []
    for run in lives:
        run["load_average_1_5_15"] = list(os.getloadavg())
    load = os.getloadavg()
    ratios = [run["live_vs_pipeline_ratio"] for run in lives]
    result = {"benchmark": "viewer", "renderer": renderer, "LP_NUM_THREADS": os.environ.get("LP_NUM_THREADS"), "size": [width, height], "machine": platform.machine(),
              "cpu_count": os.cpu_count(), "load_average_1_5_15": list(load), "splats": splats, "orbit": orbit,
              "playback": playback, "playback_fps_cached": None if playback is None else playback["fps_cached"],
              "live": lives[0] if len(lives) == 1 else lives or None,
              "orbit_fps": None if orbit is None else orbit["orbit_fps"],
              # several runs: the median, each run's own in "live"
              "live_vs_pipeline_ratio": statistics.median(ratios) if ratios else None}
    write_json(Path(args.out), result)
    print(f"wrote {args.out}")
    return 0


def demo_surface_gaussians(scene, target: int = 30_000, frame: int = 0):
    """A stand-in for the demo's trained model when no run folder is given: about ``target``
    static Gaussians on the scene's true surfaces (every k-th pixel of each train view at
    ``frame`` back-projected with its depth, coloured by the pixel, sized to the sample
    spacing), so the splat count, sizes and screen coverage are those of a trained model."""
    from app.gaussians import GaussianArrays
    from fixer4d.model.sh import SH_C0

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


# The orbit's settings: (name, adaptive resolution on, level of detail on).
ORBIT_MODES = (("lod", True, True), ("adaptive", True, False), ("full_resolution", False, False))
# Rounds of the orbit measurement: the settings take turns, so a shared machine's changing load
# hits each alike.
ORBIT_ROUNDS = 2


def bench_orbit(ctx, model: str | None, frames: int, window: tuple[int, int], rounds: int = ORBIT_ROUNDS) -> dict:
    """The whole viewer (panels + 3D view) on the demo while the mouse orbits the camera (a
    steady left-drag fed through imgui's io, one step per frame): frames per second with
    adaptive resolution and level of detail, with adaptive resolution only and with neither,
    each frame finished on the GPU before the next; ``rounds`` turns of ``frames`` frames each
    (the first 3 frames of each turn, the budget's warm-up, are not timed)."""
    from imgui_bundle import imgui

    from app.sources import app_services, initial_state
    from app.viewer import Viewer

    src, g, label = _bench_source(model)
    fbo = ctx.simple_framebuffer(window)
    out = {"model": label, "gaussians": int(g.n), "window": list(window), "rounds": rounds, "frames": frames}
    times: dict[str, list[float]] = {name: [] for name, _, _ in ORBIT_MODES}
    scales: list[float] = []
    fractions: list[float] = []
    for _ in range(rounds):
        for name, adaptive, lod in ORBIT_MODES:
            state = initial_state(src, g)
            state.show_frusta = state.show_trajectories = False
            viewer = Viewer(ctx, state, src, services=app_services())
            viewer.adaptive.enabled, viewer.adaptive.lod = adaptive, lod
            try:
                for _ in range(3):  # layout, first sort, shader warm-up
                    viewer.frame(1 / 60, fbo)
                x0, y0, w, h = viewer.viewport_rect
                io = imgui.get_io()
                io.add_mouse_pos_event(x0 + w / 2, y0 + h / 2)
                viewer.frame(1 / 60, fbo)
                io.add_mouse_button_event(0, True)
                viewer.frame(1 / 60, fbo)
                for k in range(frames + 3):
                    io.add_mouse_pos_event(x0 + w / 2 + 4.0 * (k + 1), y0 + h / 2)
                    tic = time.perf_counter()
                    viewer.frame(1 / 60, fbo)
                    gl_finish(ctx)
                    if k >= 3:
                        times[name].append(time.perf_counter() - tic)
                        if name == "lod":
                            scales.append(viewer.adaptive.scale)
                            fractions.append(viewer.splats.stats.fraction)
                io.add_mouse_button_event(0, False)
                viewer.frame(1 / 60, fbo)
            finally:
                viewer.close()
    for name, ts in times.items():
        out[f"orbit_fps_{name}"] = len(ts) / sum(ts)
        out[f"orbit_frame_ms_{name}_median"] = 1e3 * statistics.median(ts)
    out["orbit_render_scale_median"] = statistics.median(scales)
    out["orbit_lod_fraction_median"] = statistics.median(fractions)
    out["orbit_fps"] = out["orbit_fps_lod"]
    out["load_average_1_5_15"] = list(os.getloadavg())
    print(f"  orbit ({label}, {window[0]}x{window[1]} window, load {out['load_average_1_5_15'][0]:.1f}): "
          f"{out['orbit_fps_lod']:.1f} fps with level of detail (median scale {out['orbit_render_scale_median']:.2f}, "
          f"{100 * out['orbit_lod_fraction_median']:.0f}% of the splats), {out['orbit_fps_adaptive']:.1f} fps with "
          f"adaptive resolution only, {out['orbit_fps_full_resolution']:.1f} fps at full resolution", flush=True)
    return out


def bench_playback(ctx, model: str | None, window: tuple[int, int], loops: int = 2) -> dict:
    """The whole viewer (panels + 3D view, ``window`` pixels) playing the demo's timeline with
    the camera at rest, one clip frame per UI frame: the first pass draws each frame at full
    quality into the frame cache (``fill_s``: its wall time, ``fill_ms_per_frame``), the later
    ``loops - 1`` passes show the cached frames (``fps_cached``); then one pass with the cache
    off (level of detail while the time moves) for comparison (``fps_uncached``)."""
    from app.sources import app_services, initial_state
    from app.viewer import Viewer

    src, g, label = _bench_source(model)
    fbo = ctx.simple_framebuffer(window)
    state = initial_state(src, g)
    state.show_frusta = state.show_trajectories = False
    viewer = Viewer(ctx, state, src, services=app_services())
    out = {"model": label, "gaussians": int(g.n), "window": list(window), "frames": int(state.num_frames)}
    try:
        for _ in range(4):  # layout, first sort, shader warm-up, the resting full-size frame
            viewer.frame(1 / 60, fbo)
        out["viewport"] = [viewer.display_camera.width, viewer.display_camera.height]
        n = state.num_frames
        dt = 1.0001 / state.fps  # one clip frame per UI frame (a hair over: float rounding)

        def one_pass() -> list[float]:
            times = []
            for _ in range(n):
                tic = time.perf_counter()
                viewer.frame(dt, fbo)
                gl_finish(ctx)
                times.append(time.perf_counter() - tic)
            return times

        state.playing = True
        fill = one_pass()
        out["cached_frames_after_fill"] = len(viewer.frame_cache)
        cached = [t for _ in range(loops - 1) for t in one_pass()]
        out["mode_while_cached"] = viewer.view_mode
        viewer.use_frame_cache = False
        viewer.frame_cache.clear()
        uncached = one_pass()
        out["mode_while_uncached"] = viewer.view_mode
        # the 3D view alone at the window's size (no panels): what one full-quality frame costs
        state.playing = False
        viewer.use_frame_cache = True
        viewer.frame_cache.clear()
        viewer.render_view(*window)
        view_fill = []
        for f in range(n):
            state.set_frame(f)
            tic = time.perf_counter()
            viewer.render_view(*window)
            gl_finish(ctx)
            view_fill.append(time.perf_counter() - tic)
        out["view_only_size"] = list(window)
        out["view_only_fill_ms_per_frame"] = 1e3 * sum(view_fill) / len(view_fill)
        out["view_only_cached_frames"] = len(viewer.frame_cache)
    finally:
        viewer.close()
    out["fill_s"] = sum(fill)
    out["fill_ms_per_frame"] = 1e3 * sum(fill) / len(fill)
    out["fps_cached"] = len(cached) / sum(cached)
    out["fps_uncached"] = len(uncached) / sum(uncached)
    out["load_average_1_5_15"] = list(os.getloadavg())
    print(f"  playback ({label}, {window[0]}x{window[1]} window, 3D view {out['viewport'][0]}x{out['viewport'][1]}, "
          f"{n} frames, load {out['load_average_1_5_15'][0]:.1f}): filling the frame cache took {out['fill_s']:.1f} s "
          f"({out['fill_ms_per_frame']:.0f} ms a frame), then {out['fps_cached']:.1f} fps from the cache "
          f"({out['fps_uncached']:.1f} fps without it, level of detail); the 3D view alone at {window[0]}x{window[1]}: "
          f"{out['view_only_fill_ms_per_frame']:.0f} ms per full-quality frame", flush=True)
    return out


def _bench_source(model: str | None):
    """(source, gaussians, label) a viewer benchmark shows: ``model`` (a run folder or model file),
    else the demo scene's surfaces as static Gaussians."""
    from app.sources import open_source
    from app.viewer import ViewerSource
    from fixer4d.scene import load_scene

    if model:
        src, g, _ = open_source(model)
        return src, g, model
    scene = load_scene("demo")
    g = demo_surface_gaussians(scene)
    src = ViewerSource(scene=scene, label="demo (surface model)")
    return src, g, f"demo scene surfaces, {g.n} static Gaussians (no run folder given)"
