"""`fixer4d render MODEL_OR_RUN (--camera-path PATH.json | --camera ID | --trajectory PAIR) --out OUT`:
a video (.mp4/.mov/.mkv, H.264) or a PNG folder of a model along a path (docs/output.md).

--camera-path: a nerfstudio camera_path JSON (poses, fov, render_time per frame; fps).
--camera: one of the run's rig cameras, every frame of the clip (--side-by-side: next to its
  recorded frame; meant for held-out cameras).
--trajectory: one of the run's novel trajectories (the names `fixer4d trajectories` prints:
  "0-3", "0-1_arc0", ...), the camera moving along it while time sweeps the clip.
"""
from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

from fixer4d.errors import InputError

DEFAULT_FPS = 30.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("source", metavar="MODEL_OR_RUN", help="a .ply/.npz model or a run folder (runs/<name>)")
    path = parser.add_mutually_exclusive_group(required=True)
    path.add_argument("--camera-path", metavar="PATH.json", help="nerfstudio camera_path JSON")
    path.add_argument("--camera", metavar="ID", help="a rig camera of the run: its name (e.g. 30) or index")
    path.add_argument("--trajectory", metavar="PAIR", help="a novel trajectory of the run (e.g. 0-3, 0-1_arc0)")
    parser.add_argument("--out", required=True, help="video.mp4 (.mov, .mkv) or a folder for PNG frames (DIR/)")
    parser.add_argument("--frames", type=int, default=None,
                        help="--camera/--trajectory: frames to render (default: the scene's frame count)")
    parser.add_argument("--time", type=float, default=None, help="render every frame at this clip time in [0, 1)")
    parser.add_argument("--fps", type=float, default=None,
                        help="frame rate (default: the camera path's, else the scene's, else 30)")
    parser.add_argument("--side-by-side", action="store_true",
                        help="--camera: put the camera's recorded frame to the right of the render")
    parser.add_argument("--scale", type=float, default=1.0, help="--camera/--trajectory: image scale (default 1)")
    parser.add_argument("--backend", default="auto", help="render backend: auto, reference, cpu, gsplat")
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


def find_camera(scene, ident: str) -> int:
    """Index of the scene camera named ``ident``, else ``ident`` read as an index."""
    names = [c.name for c in scene.cameras]
    if ident in names:
        return names.index(ident)
    if ident.isdigit() and int(ident) < len(scene.cameras):
        return int(ident)
    raise InputError(f"--camera {ident}: no such camera; the run's cameras are {names} (or their indices "
                     f"0..{len(names) - 1})")


def _camera_path(args: argparse.Namespace):
    """(cameras, times or None, fps or None) from a nerfstudio camera_path file."""
    from fixer4d.geometry.trajectory import load_nerfstudio

    traj = load_nerfstudio(args.camera_path)
    try:
        fps = json.loads(Path(args.camera_path).read_text()).get("fps")
    except (OSError, ValueError, AttributeError):
        fps = None
    times = None if traj.times is None else [float(t) for t in traj.times]
    return traj.cameras, times, (float(fps) if isinstance(fps, (int, float)) and fps > 0 else None)


def _trajectory(src, name: str, frames: int):
    from fixer4d.geometry.trajectory import scene_trajectories

    scene, tc = src.scene, src.config.trajectories
    trajs = scene_trajectories(scene.train_cameras, frames, amplitude=tc.amplitude, arcs=tc.arcs, seed=tc.seed)
    found = [t for t in trajs if t.name == name]
    if not found:
        raise InputError(f"--trajectory {name}: no such trajectory; choose from {[t.name for t in trajs]}")
    return found[0].cameras


def _side_by_side(render_fn, scene, cam_index: int):
    """render_fn whose frames are [render | the camera's recorded frame at the nearest frame]."""
    import numpy as np
    from PIL import Image

    def fn(camera, t: float):
        frame = min(scene.num_frames - 1, max(0, int(round(t * scene.num_frames))))
        gt = scene.frame(frame, cam_index)
        if gt.shape[:2] != (camera.height, camera.width):
            gt8 = np.round(np.clip(gt, 0, 1) * 255).astype(np.uint8)
            gt = np.asarray(Image.fromarray(gt8).resize((camera.width, camera.height), Image.BILINEAR)) / 255.0
        return np.concatenate([render_fn(camera, t), gt], axis=1)

    return fn


def _check_out(out: str) -> None:
    """InputError for an --out that is neither a video nor a folder: a file name with another
    suffix (``clip.gif``) would otherwise become a folder of PNG frames under that name."""
    from fixer4d.render.video import VIDEO_FORMATS, is_video_path

    path = Path(out)
    if is_video_path(path) or out.endswith(("/", os.sep)) or path.is_dir() or not path.suffix:
        return
    raise InputError(f"--out {out}: {path.suffix} is not a video format fixer4d writes ({', '.join(VIDEO_FORMATS)}); "
                     f"name a video, or a folder for PNG frames ({path.with_suffix('')}/ or {out}/)")


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from fixer4d.cli.export import resolve_model_path
    from fixer4d.cli.output_source import clip_times, open_source
    from fixer4d.render.video import is_video_path, model_frame_fn, render_video

    if args.side_by_side and args.camera is None:
        raise InputError("--side-by-side compares with a rig camera's recorded frames; use it with --camera")
    if args.time is not None and not 0.0 <= args.time < 1.0:
        raise InputError(f"--time must be in [0, 1), got {args.time}")
    if args.scale <= 0:
        raise InputError(f"--scale must be > 0, got {args.scale}")
    _check_out(args.out)
    src = open_source(args.source, resolve_model_path(args.source))
    fps = None
    if args.camera_path is not None:
        cameras, times, fps = _camera_path(args)
        if times is None:
            times = clip_times(len(cameras))
    else:
        scene = src.scene
        frames = args.frames if args.frames is not None else scene.num_frames
        times = clip_times(frames)
        fps = scene.fps
        if args.camera is not None:
            cam_index = find_camera(scene, args.camera)
            cameras = [scene.cameras[cam_index]] * frames
        else:
            cameras = _trajectory(src, args.trajectory, frames)
        if args.scale != 1.0:
            cameras = [c.scaled(args.scale) for c in cameras]
    if args.time is not None:
        times = [args.time] * len(cameras)
    fps = args.fps if args.fps is not None else (fps or DEFAULT_FPS)
    model = src.model
    render_fn = model_frame_fn(model, args.backend, src.background)
    if args.side_by_side:
        render_fn = _side_by_side(render_fn, src.scene, find_camera(src.scene, args.camera))
    bar = tqdm(total=len(cameras), desc="render", unit="frame", disable=args.quiet)
    try:
        out = render_video(model, cameras, times, Path(args.out), fps=fps, render_fn=render_fn,
                           progress=lambda done, total: bar.update(done - bar.n))
    finally:
        bar.close()
    kind = "H.264 video" if is_video_path(out) else "PNG frames"
    print(f"{src.model_path} -> {out}: {len(cameras)} frames, {kind} at {fps:g} fps, "
          f"{cameras[0].width}x{cameras[0].height}{' (x2 side by side)' if args.side_by_side else ''}")
    return 0
