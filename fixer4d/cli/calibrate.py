"""`fixer4d calibrate CAPTURE --out rig.json`: the rig of a capture, from a ChArUco board filmed
by its cameras (``fixer4d.calib.board_calib``) when there is one, else from the capture's own
frames (structure from motion pooled over time), gated (``fixer4d.calib.gate``).

The board path is taken when ``--board`` or ``--board-capture`` is given or CAPTURE/board/
holds a board.json. ``--write-board PNG`` writes the printable board and its board.json.
"""
from __future__ import annotations

import argparse
from pathlib import Path

# The self-calibration fits no distortion: a lens that moves the image corners by more than this
# (pixels) is not lost in the keypoints' own error (~0.5-1 px) and would bend the poses.
MAX_UNMODELLED_DISTORTION_PX = 1.0


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from fixer4d.calib.board import BOARD_FOLDER, SPEC_SYNTAX
    from fixer4d.calib.board_calib import BOARD_FRAMES
    from fixer4d.calib.matchers import MATCHERS
    from fixer4d.calib.sfm import SFM_MAX_FEATURES, SFM_TIMESTAMPS

    parser.add_argument("capture", nargs="?", default=None,
                        help="capture folder: one video (mp4/mov/mkv/avi) or one image folder per camera")
    parser.add_argument("--out", default=None, help="rig.json to write (atomically)")
    parser.add_argument("--offset", action="append", default=[], metavar="CAM=N",
                        help="camera CAM's frame N is the capture's frame 0 (repeatable; on the board path: of the "
                             "board videos)")
    parser.add_argument("--frames", default=None, help="frame range a:b of the synchronized capture (or board videos) "
                                                       "to calibrate on")
    board = parser.add_argument_group("calibration board (ChArUco)")
    board.add_argument("--board", default=None, metavar="SPEC",
                       help=f"the board filmed by the cameras: {SPEC_SYNTAX}")
    board.add_argument("--board-capture", default=None, metavar="DIR",
                       help=f"the board videos, one per camera named like the capture's (default: "
                            f"CAPTURE/{BOARD_FOLDER}/ when it exists, else CAPTURE itself)")
    board.add_argument("--board-frames", type=int, default=BOARD_FRAMES,
                       help=f"frames looked at per camera, spread over the board videos (default {BOARD_FRAMES})")
    board.add_argument("--write-board", default=None, metavar="PNG",
                       help="write the board (--board, or the default one) as a PNG to print at 100 %% and its "
                            "board.json beside it")
    sfm = parser.add_argument_group("self-calibration (no board)")
    sfm.add_argument("--timestamps", type=int, default=SFM_TIMESTAMPS,
                     help=f"frames pooled per camera (default {SFM_TIMESTAMPS})")
    sfm.add_argument("--max-features", type=int, default=SFM_MAX_FEATURES,
                     help=f"keypoints per frame (default {SFM_MAX_FEATURES})")
    sfm.add_argument("--matcher", choices=MATCHERS, default="sift",
                     help="sift (default), or xfeat: XFeat + LighterGlue, a learned matcher for cameras 60-90 degrees "
                          "apart (pip install 'fixer4d[xfeat]'; CPU)")
    sfm.add_argument("--focal", action="append", default=[], metavar="[CAM=]PX[:SD]",
                     help="a focal length you know, in pixels at the videos' size, as a prior the frames are weighed "
                          "against: for every camera (--focal 466) or one (--focal cam18=515; repeatable), known to "
                          "1 %% unless SD says (pixels, or percent: --focal 466:2%%); the frames correct a prior they "
                          "contradict where they determine the focal, else the camera is refused")
    sfm.add_argument("--focal-from", default=None, metavar="RIG",
                     help="each camera's focal from a rig.json (e.g. one calibrated from a board) as its prior, "
                          "with the board's uncertainty")
    parser.add_argument("--quiet", action="store_true", help="no progress bars")


def _board_spec(args: argparse.Namespace, board_dir: Path | None):
    from fixer4d.calib.board import BOARD_JSON, parse_board, read_board_json
    from fixer4d.errors import InputError

    if args.board is not None:
        return parse_board(args.board)
    if board_dir is not None and (board_dir / BOARD_JSON).is_file():
        return read_board_json(board_dir / BOARD_JSON)
    raise InputError(f"{board_dir}: no {BOARD_JSON}; say which board was filmed with --board SPEC")


def _board_dir(args: argparse.Namespace) -> Path | None:
    """The folder of board videos when the board path is taken, else None."""
    from fixer4d.calib.board import BOARD_FOLDER, find_board
    from fixer4d.scene.capture import is_capture

    if args.board_capture is not None:
        return Path(args.board_capture)
    if args.board is None:
        found = find_board(args.capture)
        return found[0] if found else None
    inside = Path(args.capture) / BOARD_FOLDER
    return inside if is_capture(inside) else Path(args.capture)


def focal_from(path: str, files) -> dict:
    """{camera name: ``priors.FocalPrior``}: the focals (pixels at ``files``' frame size) of the
    rig.json at ``path``, with its standard deviations where it recorded them (a board rig's
    ``focal_std_rel``, else ``priors.DEFAULT_PRIOR_SD_REL``); InputError when a lens distorts by
    more than ``MAX_UNMODELLED_DISTORTION_PX``."""
    import numpy as np

    from fixer4d.calib.formats import read_calibration
    from fixer4d.calib.priors import DEFAULT_PRIOR_SD_REL, FocalPrior
    from fixer4d.calib.rig import distort_points
    from fixer4d.errors import InputError
    from fixer4d.scene.capture import match_rig

    rig = read_calibration(path, files.names)
    std = rig.checks.get("focal_std_rel") or {}
    priors = {}
    for c in match_rig(rig, files, path):
        corners = np.array([[0.0, 0.0], [c.width, 0.0], [0.0, c.height], [c.width, c.height]])
        shift = float(np.max(np.linalg.norm(distort_points(c, corners) - corners, axis=1)))
        if shift > MAX_UNMODELLED_DISTORTION_PX:
            raise InputError(f"--focal-from {path}: camera {c.name}'s lens moves the image corners by {shift:.1f} px, "
                             f"which a self-calibration does not model (at most "
                             f"{MAX_UNMODELLED_DISTORTION_PX} px): use that rig itself (--calibration) or its board "
                             f"(`fixer4d calibrate CAPTURE --board ...`)")
        f = float(c.K[0, 0])
        priors[c.name] = FocalPrior(f, f * float(std.get(c.name) or DEFAULT_PRIOR_SD_REL))
    return priors


def _uncertainty(figures: dict | None) -> str:
    """'; standard errors focal 2.1 px, rotation 0.05 deg, centre 0.3 % of the rig radius; prior ...' or ''."""
    if not figures:
        return ""
    prior = figures.get("prior")
    said = "" if prior is None else (f"; focal prior {prior['focal_px']:.1f} +- {prior['sd_px']:.1f} px "
                                     f"{prior['verdict']} (frames alone: {figures['frames_focal_px']:.1f} +- "
                                     f"{figures['frames_focal_sd_px']:.1f} px)")
    return (f"; standard errors focal {figures['focal_sd_px']:.1f} px, rotation {figures['rotation_sd_deg']:.2f} deg, "
            f"centre {100 * figures['centre_sd_rel']:.1f} % of the rig radius{said}")


def _print_rig(rig, out: str) -> None:
    from fixer4d.calib.board_calib import board_pair_table
    from fixer4d.calib.gate import pair_table

    figures = rig.checks.get("cameras", {})
    for c in rig.cameras:
        err = "n/a" if c.reprojection_error_px is None else f"{c.reprojection_error_px:.2f} px"
        lens = ", ".join(f"{k} {v:+.4f}" for k, v in c.distortion.items() if v)
        print(f"{c.name}: {c.width}x{c.height}, focal {c.K[0, 0]:.1f} px, principal point ({c.K[0, 2]:.1f}, "
              f"{c.K[1, 2]:.1f}), {lens or 'no distortion'}, reprojection {err}{_uncertainty(figures.get(c.name))}")
    if rig.pairs:
        table = board_pair_table(rig) if "shared_frames" in rig.pairs[0] else pair_table(rig)
        print(f"per pair: {table}")
    print(f"-> {out} ({rig.source}; scale: {rig.scale})")


def run(args: argparse.Namespace) -> int:
    from fixer4d.calib import calibrate
    from fixer4d.calib.board import BoardSpec, write_board_image
    from fixer4d.calib.board_calib import calibrate_board
    from fixer4d.calib.priors import parse_focal_priors
    from fixer4d.calib.sfm import SfMConfig
    from fixer4d.errors import InputError
    from fixer4d.scene import parse_frame_range
    from fixer4d.scene.capture import CaptureFiles, parse_offsets

    if args.write_board is not None:
        spec = _board_spec(args, None) if args.board is not None else BoardSpec()
        png = write_board_image(spec, args.write_board)
        print(f"-> {png} and {png.with_suffix('.json')}: {spec.describe()}. Print at 100 % scale, measure a square "
              f"and, if it is not {spec.square_m * 1000:.1f} mm, put the measured size in the board.json")
        if args.capture is None:
            return 0
    if args.capture is None or args.out is None:
        raise InputError("calibrate needs a CAPTURE folder and --out rig.json (or only --write-board PNG)")
    if args.focal and args.focal_from is not None:
        raise InputError("give --focal or --focal-from, not both")
    frame_range = parse_frame_range(args.frames) if args.frames else None
    board_dir = _board_dir(args)
    if board_dir is not None:
        spec = _board_spec(args, board_dir)
        names = None
        if board_dir.resolve() != Path(args.capture).resolve():
            # only the camera names are needed here: one frame every camera has skips the
            # synchronization check of the scene videos, which belongs to the run
            names = CaptureFiles(args.capture, frame_range=(0, 1)).names
        files = CaptureFiles(board_dir, parse_offsets(args.offset), frame_range)
        rig = calibrate_board(files, spec, names, max_frames=args.board_frames, progress=not args.quiet)
        rig.write(args.out)
    else:
        files = CaptureFiles(args.capture, parse_offsets(args.offset), frame_range)
        focal = focal_from(args.focal_from, files) if args.focal_from else parse_focal_priors(args.focal, files.names)
        config = SfMConfig(timestamps=args.timestamps, max_features=args.max_features, matcher=args.matcher,
                           focal=focal)
        rig = calibrate(files, args.out, config=config, progress=not args.quiet)
    _print_rig(rig, args.out)
    return 0
