"""Self-calibration of a capture against the true rig: the demo's four train videos and Panoptic's.

    python benchmarks/calibration.py [--demo DIR] [--panoptic-videos DIR] [--only demo|panoptic]

demo: `fixer4d make-scene demo --format n3dv` (written to a temporary folder unless --demo names
one), reduced to its four train videos: no poses_bounds.npy, no scene.json. Panoptic: the four
videos of ../shared/data/panoptic_basketball_videos; the true rig (train_meta.json) is read for
scoring only. For each capture it records

* the gate's verdict of `fixer4d calibrate` (self-calibration, focal estimated), its message and
  its wall time;
* the ungated self-calibration's error against the truth (what a run would have used without the
  gate): rotation (degrees), centre (share of the rig radius), focal (relative), after a
  similarity alignment, both the one of fixer4d.init.poses.compare_poses (rotation from the
  centres) and one whose rotation comes from the cameras' orientations (sound when the centres
  are nearly coplanar, as on the demo's 2x2 grid);
* the same with the focal length given (--focal, the lens a user knows), on the demo;
* the relative rotations between cameras (no alignment at all).

Writes benchmarks/results/calibration_demo.json and calibration_panoptic.json.
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
from fixer4d.calib.gate import problems  # noqa: E402
from fixer4d.calib.sfm import SfMConfig, calibrate_sfm  # noqa: E402
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


def evaluate_capture(capture: Path, gt: list[Camera], focal: float | None = None) -> dict:
    """The gate's verdict through the command line, then the ungated rig's errors."""
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory() as tmp:
        cmd = [sys.executable, "-m", "fixer4d.cli", "calibrate", str(capture), "--out", f"{tmp}/rig.json", "--quiet"]
        proc = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)
    out = {"command": " ".join(["fixer4d"] + cmd[3:-3] + ["--out", "rig.json"]), "gate_exit_code": proc.returncode,
           "gate_seconds": round(time.perf_counter() - t0, 1),
           "gate_message": (proc.stderr.strip().splitlines() or [""])[-1] if proc.returncode else "accepted"}
    files = CaptureFiles(capture)
    rig = calibrate_sfm(files, SfMConfig(), progress=False)
    out["self_calibration"] = score(rig, gt)
    out["self_calibration"]["gate_problems"] = problems(rig, files.names)
    if focal is not None:
        rig = calibrate_sfm(files, SfMConfig(focal=focal), progress=False)
        out["focal_given"] = {"focal_px": focal, **score(rig, gt),
                              "gate_problems": problems(rig, files.names, focal_given=True)}
    return out


def demo(folder: Path | None) -> dict:
    from fixer4d.scene import load_scene

    with tempfile.TemporaryDirectory() as tmp:
        full = folder or Path(tmp) / "demo"
        if folder is None:
            subprocess.run([sys.executable, "-m", "fixer4d.cli", "make-scene", "demo", "--format", "n3dv", "--out",
                            str(full), "--no-progress"], check=True, cwd=ROOT)
        scene = load_scene(full)
        capture = Path(tmp) / "capture"
        capture.mkdir()
        gt = [scene.cameras[i] for i in scene.train_ids]
        for c in gt:
            shutil.copy(full / f"{c.name}.mp4", capture / f"{c.name}.mp4")
        gt = sorted(gt, key=lambda c: c.name)
        return {"capture": "demo, 4 train videos only", **evaluate_capture(capture, gt, focal=gt[0].fx)}


def panoptic(videos: Path) -> dict:
    meta = json.loads((PANOPTIC / "panoptic_basketball" / "train_meta.json").read_text())
    gt = [Camera(np.array(k), np.linalg.inv(np.array(w)), int(meta["w"]), int(meta["h"]), f"cam{int(c):02d}")
          for k, w, c in zip(meta["k"][0], meta["w2c"][0], meta["cam_id"][0])]
    return {"capture": str(videos), **evaluate_capture(videos, sorted(gt, key=lambda c: c.name))}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--demo", type=Path, default=None, help="an existing `make-scene demo --format n3dv` folder")
    parser.add_argument("--panoptic-videos", type=Path, default=PANOPTIC / "panoptic_basketball_videos")
    parser.add_argument("--only", choices=["demo", "panoptic"], default=None)
    args = parser.parse_args()
    if args.only in (None, "demo"):
        result = demo(args.demo)
        atomic.write_json(RESULTS / "calibration_demo.json", result)
        print(json.dumps({k: v for k, v in result.items() if k != "pairs"}, indent=1, default=str)[:3000])
    if args.only in (None, "panoptic"):
        if not args.panoptic_videos.is_dir():
            print(f"{args.panoptic_videos}: absent, Panoptic skipped")
            return 0
        try:
            result = panoptic(args.panoptic_videos)
        except InputError as exc:
            result = {"error": str(exc)}
        atomic.write_json(RESULTS / "calibration_panoptic.json", result)
        print(json.dumps(result, indent=1, default=str)[:3000])
    return 0


if __name__ == "__main__":
    sys.exit(main())
