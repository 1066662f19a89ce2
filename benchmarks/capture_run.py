"""The demo as a user's own capture: board-calibrated (the user's path) against the given poses.

    python benchmarks/capture_run.py [--demo DIR] [--work DIR] [--seed S]
    python benchmarks/capture_run.py --summarize     # the mean over the seeds' result files

1. `fixer4d make-scene demo --format n3dv` (into WORK/demo unless --demo names such a folder).
2. WORK/capture: the demo's 4 train videos plus ONE held-out camera's video, chosen without any
   score: the held-out camera whose centre is nearest the train cameras' mean centre (ties: the
   lowest camera index; on the demo's 4x4 grid that is cam05, one of the four inner cameras).
   WORK/capture/board: synthetic ChArUco board videos of those 5 cameras
   (fixer4d.calib.board_render, the board and poses of benchmarks/calibration.py's demo case:
   filmed at 4x the videos' size, 800x600) with their board.json.
3. A (board): `fixer4d calibrate WORK/capture --out WORK/A/rig.json` (from capture/board/, the
   run's own path when no rig is given), scored against the true rig (focal, rotation, centre
   after a similarity alignment), then
   `fixer4d run WORK/capture --calibration WORK/A/rig.json --holdout CAM --out WORK/A/run`.
4. B (given poses): the true cameras written as WORK/B/rig.json, then the same run into WORK/B/run.

Both runs read the same video files and use `fixer4d run`'s defaults (those of `make run`);
`--seed S` (default: none, the runs' own default seed) passes one seed to both. A run folder that
exists is resumed by `fixer4d run` (finished stages are reused): its seconds then are not a full
run's. Writes benchmarks/results/calibration_demo_run.json (calibration errors of A, the report
rows of both runs on the held-out camera, Full_A - Full_B, commands, seconds, load average, commit);
with --seed, calibration_demo_run_seed<S>.json. `--summarize` writes their per-seed and mean
figures to calibration_demo_run_mean.json.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from calibration import (BOARD_POSES, BOARD_TILT_DEG, DEMO_BOARD, DEMO_BOARD_DISTANCE,  # noqa: E402
                         DEMO_BOARD_SPREAD, board_score)
from fixer4d import atomic  # noqa: E402
from fixer4d.calib.board_render import board_poses, write_board_capture  # noqa: E402
from fixer4d.calib.rig import read_rig_json, rig_from_cameras  # noqa: E402
from fixer4d.geometry.camera import Camera  # noqa: E402
from fixer4d.pipeline.run_folder import source_commit  # noqa: E402

RESULTS = ROOT / "benchmarks" / "results"
# The board is filmed at the cameras' full resolution, 4x the demo videos' 200x150: at 200x150
# its markers (~11 px) decode in too few frames and `fixer4d calibrate` refuses (calibration_board.json).
BOARD_FILM_FACTOR = 4
# The report rows recorded per run (every row the report has; these two are the done-when's).
KEY_ROWS = ("STGS w/ MVS", "Full")
# The acceptance bar: the board-calibrated run's Full PSNR within this of the given-pose run's.
DONE_WHEN_DB = 0.3
MEAN_FILE = "calibration_demo_run_mean.json"


def _cli(*args: str) -> list[str]:
    return [sys.executable, "-m", "fixer4d.cli", *args]


def _shown(cmd: list[str], work: Path) -> str:
    """A command as a user types it, the work folder written as WORK."""
    return " ".join(["fixer4d"] + [a.replace(str(work), "WORK") for a in cmd[3:]])


def held_out_camera(cameras: list[Camera], train_ids: list[int], test_ids: list[int]) -> int:
    """The held-out camera nearest the train cameras' mean centre (ties, to 1e-9 of the rig's
    size, go to the lowest index): a rule on the rig alone, never on a score."""
    centre = np.mean([cameras[i].center for i in train_ids], 0)
    size = max(np.linalg.norm(cameras[i].center - centre) for i in train_ids)
    dist = {i: round(float(np.linalg.norm(cameras[i].center - centre)) / size, 9) for i in test_ids}
    return min(test_ids, key=lambda i: (dist[i], i))


def write_capture(demo_dir: Path, capture: Path) -> tuple[list[Camera], str]:
    """capture/: the train videos and the chosen held-out video of ``demo_dir``, capture/board/:
    board videos of those cameras. Returns the true cameras (name order) and the held-out name."""
    from fixer4d.scene import load_scene

    scene = load_scene(demo_dir)
    cams = scene.cameras
    held = held_out_camera(cams, list(scene.train_ids), list(scene.test_ids))
    chosen = sorted([*scene.train_ids, held], key=lambda i: cams[i].name)
    if capture.exists():
        shutil.rmtree(capture)
    capture.mkdir(parents=True)
    for i in chosen:
        shutil.copy(demo_dir / f"{cams[i].name}.mp4", capture / f"{cams[i].name}.mp4")
    truth = [cams[i] for i in chosen]
    big = [c.scaled(BOARD_FILM_FACTOR) for c in truth]
    centre = np.mean([c.center for c in truth], 0)
    forward = np.mean([c.forward for c in truth], 0)
    poses = board_poses(DEMO_BOARD, big, centre + DEMO_BOARD_DISTANCE * forward, DEMO_BOARD_SPREAD,
                        count=BOARD_POSES, tilt_deg=BOARD_TILT_DEG, seed=0)
    write_board_capture(DEMO_BOARD, big, poses, capture / "board")
    return truth, cams[held].name


def run_rows(run: Path) -> dict:
    """The report rows of a run folder by method, and its stage seconds."""
    report = json.loads((run / "report.json").read_text())
    rows = {r["method"]: {k: v for k, v in r.items() if k != "method"} for r in report["rows"]}
    return {"rows": rows, "stage_seconds": report.get("stage_seconds"), "scene": report.get("scene"),
            "restorer": report.get("restorer"), "self_check": report.get("self_check")}


def timed(cmd: list[str], log: Path) -> dict:
    """Runs ``cmd`` (output to ``log``); exit code, wall seconds, load average before and after."""
    load0 = os.getloadavg()
    t0 = time.perf_counter()
    with open(log, "w") as fh:
        code = subprocess.run(cmd, stdout=fh, stderr=subprocess.STDOUT, cwd=ROOT).returncode
    return {"exit_code": code, "seconds": round(time.perf_counter() - t0, 1),
            "load_average_before": [round(x, 2) for x in load0],
            "load_average_after": [round(x, 2) for x in os.getloadavg()]}


def summarize(files: list[Path]) -> dict:
    """Per-seed and mean STGS w/ MVS and Full of runs A and B over result files of this script
    (those whose runs both finished), and the mean Full A - B against the acceptance bar."""
    seeds = []
    for f in files:
        rec = json.loads(Path(f).read_text())
        if "summary" not in rec:
            continue
        seeds.append({"file": Path(f).name, "seed": rec.get("seed"), "commit": rec.get("commit"),
                      **{n: rec["summary"][n] for n in "AB"}, "full_A_minus_B_db": rec["full_A_minus_B_db"]})
    if not seeds:
        raise SystemExit("no finished capture runs among " + ", ".join(str(f) for f in files))
    mean = {n: {m: float(np.mean([s[n][m] for s in seeds])) for m in KEY_ROWS} for n in "AB"}
    diff = mean["A"]["Full"] - mean["B"]["Full"]
    return {"seeds": seeds, "mean": mean, "full_A_minus_B_db": diff,
            "spread_full_A_minus_B_db": [min(s["full_A_minus_B_db"] for s in seeds),
                                         max(s["full_A_minus_B_db"] for s in seeds)],
            "done_when": {"threshold_db": DONE_WHEN_DB, "met": abs(diff) <= DONE_WHEN_DB}}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--demo", type=Path, default=None, help="an existing `make-scene demo --format n3dv` folder")
    parser.add_argument("--work", type=Path, default=ROOT / "runs" / "capture_run", help="capture and run folders")
    parser.add_argument("--seed", type=int, default=None, help="one seed for both runs (default: the runs' default)")
    parser.add_argument("--summarize", action="store_true",
                        help="run nothing: the mean over the committed calibration_demo_run*.json seeds "
                             "-> calibration_demo_run_mean.json")
    args = parser.parse_args()
    if args.summarize:
        files = sorted(f for f in RESULTS.glob("calibration_demo_run*.json") if f.name != MEAN_FILE)
        out = summarize(files)
        atomic.write_json(RESULTS / MEAN_FILE, out)
        print(json.dumps(out, indent=1))
        return 0
    work = args.work.resolve()
    work.mkdir(parents=True, exist_ok=True)
    demo_dir = args.demo
    if demo_dir is None:
        demo_dir = work / "demo"
        subprocess.run(_cli("make-scene", "demo", "--format", "n3dv", "--out", str(demo_dir), "--no-progress"),
                       check=True, cwd=ROOT)
    capture = work / "capture"
    truth, held = write_capture(demo_dir.resolve(), capture)
    out = {"scene": "demo (fixer4d make-scene demo --format n3dv), as a capture folder",
           "cameras": [c.name for c in truth], "held_out": held,
           "held_out_rule": "the held-out camera nearest the train cameras' mean centre (ties: lowest index)",
           "board": {"spec": DEMO_BOARD.describe(), "videos": f"{len(truth)} cameras at "
                     f"{truth[0].width * BOARD_FILM_FACTOR}x{truth[0].height * BOARD_FILM_FACTOR}, "
                     f"{BOARD_POSES} poses tilted up to {BOARD_TILT_DEG:g} deg, {DEMO_BOARD_DISTANCE} m ahead"},
           "seed": args.seed, "commit": source_commit(), "cores": os.cpu_count()}

    (work / "A").mkdir(exist_ok=True)
    (work / "B").mkdir(exist_ok=True)
    cmd = _cli("calibrate", str(capture), "--out", str(work / "A" / "rig.json"), "--quiet")
    cal = timed(cmd, work / "A" / "calibrate.log")
    cal["command"] = _shown(cmd, work)
    if cal["exit_code"] != 0:
        cal["message"] = (work / "A" / "calibrate.log").read_text().strip().splitlines()[-1:]
        out["calibration_A"] = cal
        atomic.write_json(RESULTS / "calibration_demo_run.json", out)
        print(json.dumps(out, indent=1))
        return 1
    rig = read_rig_json(work / "A" / "rig.json")
    by_name = rig.by_name()
    rig.cameras = [by_name[g.name].resized(g.width, g.height) for g in truth]
    errors = board_score(rig, truth, {})
    cal["errors"] = {"focal_rel_error_max": max(abs(e) for e in errors["focal_rel_error"]),
                     "rotation_deg_max": errors["centre_aligned"]["rotation_deg_max"],
                     "centre_error_rel_max": errors["centre_aligned"]["center_error_rel_max"],
                     "relative_rotation_deg_max": errors["relative_rotation_deg_max"],
                     "principal_point_error_px_max": max(errors["principal_point_error_px"]),
                     "scale": errors["scale"], "reprojection_error_px": errors["reprojection_error_px"],
                     "lens_model": errors["lens_model"]}
    out["calibration_A"] = cal
    rig_from_cameras(truth, source="the demo's true cameras (the given poses)",
                     scale="the demo's world units").write(work / "B" / "rig.json")

    seed = [] if args.seed is None else ["--seed", str(args.seed)]
    for name in ("A", "B"):
        cmd = _cli("run", str(capture), "--calibration", str(work / name / "rig.json"), "--holdout", held,
                   "--out", str(work / name / "run"), "--quiet", *seed)
        rec = timed(cmd, work / name / "run.log")
        rec["command"] = _shown(cmd, work)
        if rec["exit_code"] == 0:
            rec.update(run_rows(work / name / "run"))
        out[f"run_{name}"] = rec
    if all(out[f"run_{n}"]["exit_code"] == 0 for n in "AB"):
        a, b = out["run_A"]["rows"], out["run_B"]["rows"]
        out["psnr_A_minus_B"] = {m: a[m]["psnr"] - b[m]["psnr"] for m in a if m in b
                                 and a[m].get("psnr") is not None and b[m].get("psnr") is not None}
        out["full_A_minus_B_db"] = out["psnr_A_minus_B"]["Full"]
        out["done_when"] = {"threshold_db": DONE_WHEN_DB, "met": abs(out["full_A_minus_B_db"]) <= DONE_WHEN_DB}
        out["summary"] = {name: {m: round(out[f"run_{name}"]["rows"][m]["psnr"], 3) for m in KEY_ROWS} for name in "AB"}
    name = "calibration_demo_run.json" if args.seed is None else f"calibration_demo_run_seed{args.seed}.json"
    atomic.write_json(RESULTS / name, out)
    print(json.dumps({k: v for k, v in out.items() if not k.startswith("run_")}, indent=1, default=str))
    return 0


if __name__ == "__main__":
    sys.exit(main())
