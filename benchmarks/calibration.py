"""Calibration of a capture against the true rig: self-calibration of the demo's four train videos
and Panoptic's, and calibration from synthetic ChArUco board videos.

    python benchmarks/calibration.py [--demo DIR] [--panoptic-videos DIR] [--only demo|panoptic|board]
                                     [--matcher sift|xfeat] [--timestamps T] [--max-features N]

demo: `fixer4d make-scene demo --format n3dv` (written to a temporary folder unless --demo names
one), reduced to its four train videos: no poses_bounds.npy, no scene.json. Panoptic: the four
videos of ../shared/data/panoptic_basketball_videos; the true rig (train_meta.json) is read for
scoring only. For each capture, twice: the focals estimated, and a focal given for every camera
(--focal: the demo's true one; Panoptic's 466 px, true for two of its four cameras), it records

* `fixer4d calibrate`'s verdict (the gate), its message and its wall time;
* the ungated self-calibration (what a run would have used without the gate): each camera's
  focal, rotation and centre standard errors and the prior's verdict (``checks.cameras``), and its
  error against the truth: rotation (degrees), centre (share of the rig radius), focal
  (relative), after a similarity alignment, both the one of fixer4d.init.poses.compare_poses
  (rotation from the centres) and one whose rotation comes from the cameras' orientations (sound
  when the centres are nearly coplanar, as on the demo's 2x2 grid); the relative rotations
  between cameras (no alignment at all); the matches per pair.

`--matcher xfeat` (with `--timestamps`, `--max-features`) calibrates Panoptic with XFeat +
LighterGlue instead of SIFT.

Board (``board``): exact board videos (fixer4d.calib.board_render: a ChArUco board at 30 poses
tilted up to 40 degrees, mild blur and noise) of
* four cameras converging on the volume (an arc of 70 degrees, 1.5 m away), 320x240 and 640x480,
  two of them behind distorting lenses;
* the demo's four train cameras (parallel 2x2 grid) filmed at 4x their 200x150 video size, the
  rig then used at 200x150; the same board at 200x150 itself; and the workflow that fixes the
  self-calibration's focal with the board's (`fixer4d calibrate CAPTURE --focal-from rig.json`).
Each through `fixer4d calibrate` (its wall time), scored like the self-calibration plus the
principal point, the metric scale (the alignment's scale: 1 = metres recovered) and the lens
(largest displacement error over the central 70 % of the image).

Writes benchmarks/results/calibration_demo.json, calibration_panoptic.json (calibration_panoptic_xfeat.json
with --matcher xfeat), calibration_board.json.
"""
from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from fixer4d import atomic  # noqa: E402
from fixer4d.calib.board import BoardSpec  # noqa: E402
from fixer4d.calib.board_render import board_poses, write_board_capture  # noqa: E402
from fixer4d.calib.gate import problems  # noqa: E402
from fixer4d.calib.rig import RigCamera, distort_points, read_rig_json  # noqa: E402
from fixer4d.calib.matchers import MATCHERS  # noqa: E402
from fixer4d.calib.priors import parse_focal_priors  # noqa: E402
from fixer4d.calib.sfm import SFM_MAX_FEATURES, SFM_TIMESTAMPS, SfMConfig, calibrate_sfm  # noqa: E402
from fixer4d.errors import InputError  # noqa: E402
from fixer4d.geometry.camera import Camera, rig_extent  # noqa: E402
from fixer4d.init.poses import compare_poses  # noqa: E402
from fixer4d.scene.capture import CaptureFiles  # noqa: E402

RESULTS = ROOT / "benchmarks" / "results"
PANOPTIC = ROOT.parent / "shared" / "data"


def _angle(R: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1, 1))))


def orientation_aligned_errors(est: list[Camera], gt: list[Camera]) -> dict:
    """Rotation of the alignment = chordal mean of R_gt R_est^T; scale and offset from the centres."""
    U, _, Vt = np.linalg.svd(np.sum([g.R @ e.R.T for e, g in zip(est, gt)], 0))
    S = np.eye(3)
    S[2, 2] = np.sign(np.linalg.det(U @ Vt))
    R = U @ S @ Vt
    ce = np.stack([c.center for c in est])
    cg = np.stack([c.center for c in gt])
    xe, xg = (ce - ce.mean(0)) @ R.T, cg - cg.mean(0)
    s = float(np.sum(xg * xe) / np.sum(xe * xe))
    radius = rig_extent(gt)
    rot = [_angle(g.R.T @ R @ e.R) for e, g in zip(est, gt)]
    cen = [float(np.linalg.norm(s * a - b) / radius) for a, b in zip(xe, xg)]
    return {"rotation_deg_max": max(rot), "center_error_rel_max": max(cen), "per_camera_rotation_deg": rot,
            "per_camera_center_error_rel": cen}


def score(rig, gt: list[Camera]) -> dict:
    if len(rig.cameras) != len(gt):
        return {"registered": [c.name for c in rig.cameras]}
    est = [c.camera() for c in rig.cameras]
    centres = compare_poses(est, gt)
    rel = [_angle((est[i].R.T @ est[j].R).T @ (gt[i].R.T @ gt[j].R))
           for i in range(len(gt)) for j in range(i + 1, len(gt))]
    return {"centre_aligned": {k: centres[k] for k in ("rotation_deg_max", "center_error_rel_max")},
            "orientation_aligned": orientation_aligned_errors(est, gt),
            "relative_rotation_deg_max": max(rel),
            "focal_rel_error": [e.fx / g.fx - 1 for e, g in zip(est, gt)],
            "reprojection_error_px": [c.reprojection_error_px for c in rig.cameras],
            "checks": {k: v for k, v in rig.checks.items() if k != "gate"}, "pairs": rig.pairs}


def evaluate_capture(capture: Path, gt: list[Camera], focal: list[str] | None = None,
                     sfm: tuple[str, ...] = ()) -> dict:
    """The gate's verdict through the command line, then the ungated rig's errors; ``focal``: the
    --focal arguments of a second case (a focal the user gives); ``sfm``: more calibrate arguments
    (e.g. --matcher xfeat)."""
    files = CaptureFiles(capture)
    names = [c.name for c in gt]
    config = sfm_config(sfm)
    out = {"self_calibration": _case(capture, files, gt, config, [], sfm)}
    if focal:
        config.focal = parse_focal_priors(focal, names)
        out["focal_given"] = _case(capture, files, gt, config, focal, sfm)
    return out


def sfm_config(sfm: tuple[str, ...]) -> SfMConfig:
    """The SfMConfig the command line builds from ``sfm`` (--matcher, --timestamps, --max-features)."""
    args = dict(zip(sfm[::2], sfm[1::2]))
    return SfMConfig(matcher=args.get("--matcher", "sift"), timestamps=int(args.get("--timestamps", SFM_TIMESTAMPS)),
                     max_features=int(args.get("--max-features", SFM_MAX_FEATURES)))


def _case(capture: Path, files, gt: list[Camera], config: SfMConfig, focal: list[str], sfm: tuple[str, ...]) -> dict:
    """`fixer4d calibrate` (its exit code, wall time and message) and the rig it judged, ungated, scored."""
    extra = [*sfm, *(a for f in focal for a in ("--focal", f))]
    with tempfile.TemporaryDirectory() as tmp:
        gate = _calibrate_cli(capture, Path(tmp) / "rig.json", *extra)
    rig = calibrate_sfm(files, config, progress=False)
    return {**gate, **score(rig, gt), "gate_problems": problems(rig, files.names)}


def demo_capture(folder: Path | None, tmp: Path) -> tuple[Path, list[Camera]]:
    """The demo's four train videos in tmp/capture (the demo written to tmp/demo unless ``folder``
    names one) and their true cameras, in name order."""
    from fixer4d.scene import load_scene

    full = folder or tmp / "demo"
    if folder is None:
        subprocess.run([sys.executable, "-m", "fixer4d.cli", "make-scene", "demo", "--format", "n3dv", "--out",
                        str(full), "--no-progress"], check=True, cwd=ROOT)
    scene = load_scene(full)
    capture = tmp / "capture"
    capture.mkdir()
    gt = [scene.cameras[i] for i in scene.train_ids]
    for c in gt:
        shutil.copy(full / f"{c.name}.mp4", capture / f"{c.name}.mp4")
    return capture, sorted(gt, key=lambda c: c.name)


def demo(folder: Path | None) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        capture, gt = demo_capture(folder, Path(tmp))
        return {"capture": "demo, 4 train videos only", **evaluate_capture(capture, gt, focal=[str(gt[0].fx)])}


# The converging rig of tests/calib/test_board.py and its board: 0.84 x 0.6 m, 1.5 m from the cameras.
CONVERGING_RIG = {"layout": "arc", "count": 4, "radius": 1.5, "arc_deg": 70, "height_offset": 0.4,
                  "fov_y_deg": 50, "target": [0.0, 0.1, 0.0]}
CONVERGING_BOARD = BoardSpec(7, 5, 0.12, 0.09, "DICT_4X4_50")
CONVERGING_VOLUME = (np.array([0.0, 0.1, 0.0]), np.array([0.3, 0.2, 0.3]))
# Two lenses: strong barrel (k1, k2) and mild pincushion with the tangential terms of a slightly
# decentred lens; the other two cameras are pinholes.
LENSES = {"cam01": {"k1": -0.2, "k2": 0.08}, "cam03": {"k1": 0.1, "p1": 0.0005, "p2": -0.0003}}
# The demo's cameras stand ~4 m from its scene; a 1.4 x 1.0 m board held 2.5 m in front of them.
DEMO_BOARD = BoardSpec(7, 5, 0.2, 0.15, "DICT_4X4_50")
DEMO_BOARD_DISTANCE = 2.5
DEMO_BOARD_SPREAD = np.array([0.4, 0.3, 0.4])
BOARD_POSES = 30
BOARD_TILT_DEG = 40.0


def _calibrate_cli(capture: Path, out: Path, *extra: str) -> dict:
    """`fixer4d calibrate CAPTURE --out OUT ...` in a subprocess: exit code, wall time, last error line."""
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "fixer4d.cli", "calibrate", str(capture), "--out", str(out),
                           "--quiet", *extra], capture_output=True, text=True, cwd=ROOT)
    shown = [Path(e).name if "/" in e else e for e in extra]  # no temporary folders in the record
    return {"command": " ".join(["fixer4d calibrate", capture.name, "--out", out.name, *shown]),
            "exit_code": proc.returncode, "seconds": round(time.perf_counter() - t0, 2),
            "message": (proc.stderr.strip().splitlines() or [""])[-1] if proc.returncode else "accepted"}


def board_score(rig, gt: list[Camera], lenses: dict) -> dict:
    """``score`` plus the principal point (px), the alignment's scale and the lens error (px)."""
    est = [c.camera() for c in rig.cameras]
    u, v = np.meshgrid(np.linspace(0.15, 0.85, 15), np.linspace(0.15, 0.85, 11))
    lens_err = []
    for c, g in zip(rig.cameras, gt):
        grid = np.stack([u.ravel() * g.width, v.ravel() * g.height], 1)
        truth = RigCamera(g.name, g.width, g.height, g.K, np.eye(4), lenses.get(g.name, {}))
        lens_err.append(float(np.abs(distort_points(c, grid) - distort_points(truth, grid)).max()))
    return {**score(rig, gt), "scale": compare_poses(est, gt)["scale"],
            "principal_point_error_px": [float(np.hypot(e.cx - g.cx, e.cy - g.cy)) for e, g in zip(est, gt)],
            "lens_error_px_max": lens_err, "lens_model": rig.checks.get("lens_model"),
            "frames_with_board": rig.checks.get("frames_with_board")}


def board_case(cameras: list[Camera], spec: BoardSpec, volume: tuple, lenses: dict, tmp: Path,
               score_at: list[Camera] | None = None) -> dict:
    """Board videos of ``cameras``, calibrated by `fixer4d calibrate`; scored against ``score_at``
    (the same cameras at another size; default ``cameras``) with the rig resized to it."""
    poses = board_poses(spec, cameras, *volume, count=BOARD_POSES, tilt_deg=BOARD_TILT_DEG, seed=0)
    write_board_capture(spec, cameras, poses, tmp / "board", distortion=lenses)
    out = {"board": spec.describe(), "cameras": f"{len(cameras)} at {cameras[0].width}x{cameras[0].height}",
           **_calibrate_cli(tmp / "board", tmp / "rig.json", "--board", str(tmp / "board" / "board.json"))}
    if out["exit_code"] == 0:
        rig = read_rig_json(tmp / "rig.json")
        gt = score_at or cameras
        rig.cameras = [c.resized(g.width, g.height) for c, g in zip(rig.cameras, gt)]
        out.update(board_score(rig, gt, lenses))
    return out


def board(folder: Path | None) -> dict:
    from fixer4d.scene.synthetic import build_rig

    result = {}
    for w, h in ((320, 240), (640, 480)):
        cams = build_rig({"rig": {**CONVERGING_RIG, "width": w, "height": h}})
        with tempfile.TemporaryDirectory() as tmp:
            result[f"converging_{w}x{h}"] = board_case(cams, CONVERGING_BOARD, CONVERGING_VOLUME, LENSES, Path(tmp))
    with tempfile.TemporaryDirectory() as tmp:
        capture, gt = demo_capture(folder, Path(tmp))
        centre = np.mean([c.center for c in gt], 0)
        forward = np.mean([c.forward for c in gt], 0)
        volume = (centre + DEMO_BOARD_DISTANCE * forward, DEMO_BOARD_SPREAD)
        for factor in (4, 1):
            with tempfile.TemporaryDirectory() as sub:
                big = [c.scaled(factor) for c in gt]
                key = f"demo_parallel_{big[0].width}x{big[0].height}"
                result[key] = board_case(big, DEMO_BOARD, volume, {}, Path(sub), score_at=gt)
                if factor == 4 and result[key]["exit_code"] == 0:
                    shutil.copy(Path(sub) / "rig.json", Path(tmp) / "board_rig.json")
        # the workflow for a rig whose geometry cannot fix the focal: the board's focal, the frames' poses
        flow = _calibrate_cli(capture, Path(tmp) / "rig.json", "--focal-from", str(Path(tmp) / "board_rig.json"))
        if flow["exit_code"] == 0:
            flow.update(score(read_rig_json(Path(tmp) / "rig.json"), gt))
        result["demo_self_calibration_with_board_focal"] = flow
    return result


def panoptic(videos: Path, sfm: tuple[str, ...]) -> dict:
    """The four Panoptic videos against their given rig; the focal case is `--focal 466`, the
    focal of two of the four cameras given for all (the other two are 515 and 524 px)."""
    meta = json.loads((PANOPTIC / "panoptic_basketball" / "train_meta.json").read_text())
    gt = [Camera(np.array(k), np.linalg.inv(np.array(w)), int(meta["w"]), int(meta["h"]), f"cam{int(c):02d}")
          for k, w, c in zip(meta["k"][0], meta["w2c"][0], meta["cam_id"][0])]
    return {"capture": str(videos), **evaluate_capture(videos, sorted(gt, key=lambda c: c.name), ["466"], sfm)}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--demo", type=Path, default=None, help="an existing `make-scene demo --format n3dv` folder")
    parser.add_argument("--panoptic-videos", type=Path, default=PANOPTIC / "panoptic_basketball_videos")
    parser.add_argument("--only", choices=["demo", "panoptic", "board"], default=None)
    parser.add_argument("--matcher", choices=MATCHERS, default="sift",
                        help="the self-calibration's matcher; xfeat writes calibration_panoptic_xfeat.json")
    parser.add_argument("--timestamps", type=int, default=None)
    parser.add_argument("--max-features", type=int, default=None)
    args = parser.parse_args()
    sfm = ("--matcher", args.matcher, *(("--timestamps", str(args.timestamps)) if args.timestamps else ()),
           *(("--max-features", str(args.max_features)) if args.max_features else ()))
    if args.only in (None, "demo"):
        result = demo(args.demo)
        atomic.write_json(RESULTS / "calibration_demo.json", result)
        print(json.dumps({k: v for k, v in result.items() if k != "pairs"}, indent=1, default=str)[:3000])
    if args.only in (None, "board"):
        result = board(args.demo)
        atomic.write_json(RESULTS / "calibration_board.json", result)
        print(json.dumps(result, indent=1, default=str)[:4000])
    if args.only in (None, "panoptic"):
        if not args.panoptic_videos.is_dir():
            print(f"{args.panoptic_videos}: absent, Panoptic skipped")
            return 0
        try:
            result = panoptic(args.panoptic_videos, sfm)
        except InputError as exc:
            result = {"error": str(exc)}
        suffix = "" if args.matcher == "sift" else f"_{args.matcher}"
        atomic.write_json(RESULTS / f"calibration_panoptic{suffix}.json", {"arguments": list(sfm), **result})
        print(json.dumps(result, indent=1, default=str)[:3000])
    return 0


if __name__ == "__main__":
    sys.exit(main())
