"""`fixer4d trajectories SCENE --out presets.json`: pair paths and diagonal arcs of a scene's
train cameras, saved as fixer4d presets (and optionally as a nerfstudio camera path)."""
from __future__ import annotations

import argparse
from pathlib import Path


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from fixer4d.geometry.trajectory import ARC_AMPLITUDE_RANGE, DEFAULT_FRAMES

    parser.add_argument("scene", metavar="SCENE",
                        help="'demo', a scene spec .json, a scene folder, or a run folder (its scene, and by default "
                             "the trajectories its stage 2 restored)")
    parser.add_argument("--out", required=True, help="preset JSON to write (fixer4d-trajectories format)")
    parser.add_argument("--nerfstudio", metavar="PATH.json",
                        help="also write a nerfstudio camera_path JSON (all trajectories back to back, or --only)")
    parser.add_argument("--frames", type=int, default=None,
                        help=f"frames per trajectory (default: a run's, else {DEFAULT_FRAMES})")
    parser.add_argument("--amplitude", type=float, default=None,
                        help="arc amplitude A in world units (default: drawn in "
                             f"[{ARC_AMPLITUDE_RANGE[0]}, {ARC_AMPLITUDE_RANGE[1]}] x baseline with --seed)")
    parser.add_argument("--seed", type=int, default=None, help="seed for drawn amplitudes (default: a run's, else 0)")
    parser.add_argument("--no-arcs", action="store_true", help="only the straight pair trajectories")
    parser.add_argument("--only", metavar="NAME", action="append",
                        help="keep only this trajectory (e.g. 0-3_arc0); repeatable")
    parser.add_argument("--time", type=float, default=None,
                        help="render_time in [0, 1) for every nerfstudio frame (default: time sweeps with the frames)")
    parser.add_argument("--scale", type=float, default=1.0, help="image scale of the scene's cameras (default 1)")


def run(args: argparse.Namespace) -> int:
    from fixer4d.errors import InputError
    from fixer4d.geometry.trajectory import DEFAULT_FRAMES, save_nerfstudio, save_presets, scene_trajectories
    from fixer4d.pipeline.config import TrajectoryConfig
    from fixer4d.pipeline.run_folder import CONFIG_NAME, load_scene_for, read_run_config
    from fixer4d.scene import load_scene

    if args.scale <= 0:
        raise InputError(f"--scale must be > 0, got {args.scale}")
    run = Path(args.scene)
    if run.is_dir() and (run / CONFIG_NAME).is_file():  # a run folder: its scene at its scale, its stage-2 settings
        config = read_run_config(run)
        scene, tc = load_scene_for(config), config.trajectories
        train = [scene.cameras[i].scaled(args.scale) if args.scale != 1.0 else scene.cameras[i] for i in scene.train_ids]
    else:
        scene, tc = load_scene(args.scene, scale=args.scale), TrajectoryConfig(frames=DEFAULT_FRAMES)
        train = [scene.cameras[i] for i in scene.train_ids]
    frames = tc.frames if args.frames is None else args.frames
    seed = tc.seed if args.seed is None else args.seed
    amplitude = tc.amplitude if args.amplitude is None else args.amplitude
    trajs = scene_trajectories(train, frames, amplitude=amplitude, arcs=tc.arcs and not args.no_arcs, seed=seed)
    if args.only:
        unknown = sorted(set(args.only) - {t.name for t in trajs})
        if unknown:
            raise InputError(f"--only {unknown}: no such trajectory; choose from {[t.name for t in trajs]}")
        trajs = [t for t in trajs if t.name in args.only]
    meta = {"scene": str(args.scene), "scale": args.scale, "train_cameras": [c.name for c in train],
            "train_ids": list(scene.train_ids)}
    out = save_presets(trajs, args.out, meta=meta)
    for t in trajs:
        a, b = t.pair if t.pair else (None, None)
        print(f"{t.name:>10}  {train[a].name if a is not None else '?'} -> {train[b].name if b is not None else '?'}  "
              f"A = {t.amplitude:.4f}  {t.frames} frames")
    print(f"wrote {len(trajs)} trajectories to {out}")
    if args.nerfstudio:
        ns = save_nerfstudio(trajs, args.nerfstudio, render_time=args.time)
        print(f"wrote nerfstudio camera path ({sum(t.frames for t in trajs)} frames) to {ns}")
    return 0
