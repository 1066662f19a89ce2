"""`fixer4d calibrate CAPTURE --out rig.json`: the rig of a capture from its own frames (structure
from motion pooled over time), gated (``fixer4d.calib.gate``)."""
from __future__ import annotations

import argparse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from fixer4d.calib.sfm import SFM_MAX_FEATURES, SFM_TIMESTAMPS

    parser.add_argument("capture", help="capture folder: one video (mp4/mov/mkv/avi) or one image folder per camera")
    parser.add_argument("--out", required=True, help="rig.json to write (atomically)")
    parser.add_argument("--offset", action="append", default=[], metavar="CAM=N",
                        help="camera CAM's frame N is the capture's frame 0 (repeatable)")
    parser.add_argument("--frames", default=None, help="frame range a:b of the synchronized capture to calibrate on")
    parser.add_argument("--timestamps", type=int, default=SFM_TIMESTAMPS,
                        help=f"frames pooled per camera (default {SFM_TIMESTAMPS})")
    parser.add_argument("--max-features", type=int, default=SFM_MAX_FEATURES,
                        help=f"SIFT features per frame (default {SFM_MAX_FEATURES})")
    parser.add_argument("--intrinsics", choices=["shared", "per-camera"], default="shared",
                        help="one lens model for every camera (same cameras) or one each")
    parser.add_argument("--focal", type=float, default=None,
                        help="known focal length in pixels at the video's resolution (held fixed)")
    parser.add_argument("--quiet", action="store_true", help="no progress bars")


def run(args: argparse.Namespace) -> int:
    from fixer4d.calib import calibrate
    from fixer4d.calib.gate import pair_table
    from fixer4d.calib.sfm import SfMConfig
    from fixer4d.scene import parse_frame_range
    from fixer4d.scene.capture import CaptureFiles, parse_offsets

    frame_range = parse_frame_range(args.frames) if args.frames else None
    files = CaptureFiles(args.capture, parse_offsets(args.offset), frame_range)
    config = SfMConfig(timestamps=args.timestamps, max_features=args.max_features, intrinsics=args.intrinsics,
                       focal=args.focal)
    rig = calibrate(files, args.out, config=config, progress=not args.quiet)
    for c in rig.cameras:
        err = "n/a" if c.reprojection_error_px is None else f"{c.reprojection_error_px:.2f} px"
        print(f"{c.name}: {c.width}x{c.height}, focal {c.K[0, 0]:.1f} px, k1 {c.distortion['k1']:+.4f}, "
              f"reprojection {err}")
    if rig.pairs:
        print(f"matches per pair: {pair_table(rig)}")
    print(f"-> {args.out} ({rig.source}; scale: {rig.scale})")
    return 0
