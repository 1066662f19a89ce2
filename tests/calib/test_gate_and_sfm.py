"""Self-calibration end to end on a small synthetic capture, and the gate that refuses an
untrustworthy rig in one message (camera, per-pair matches, what to do)."""
from __future__ import annotations

import json

import numpy as np
import pytest

from fixer4d.calib.gate import MAX_CENTRE_SD_REL, MAX_FOCAL_SD_REL, check_rig, problems
from fixer4d.calib.rig import Rig, RigCamera
from fixer4d.errors import InputError
from fixer4d.geometry.camera import Camera


def _pair(a, b, verified, shared=300):
    return {"cameras": [a, b], "raw_matches": verified + 50, "verified_matches": verified, "shared_points": shared}


def _figures(focal_sd=1.0, rotation_sd=0.1, centre_sd=0.004, verdict=None) -> dict:
    prior = None if verdict is None else {"focal_px": 150.0, "sd_px": 1.5, "verdict": verdict}
    return {"focal_px": 160.8, "focal_sd_px": focal_sd, "rotation_sd_deg": rotation_sd, "centre_sd_rel": centre_sd,
            "frames_focal_px": 160.8, "frames_focal_sd_px": focal_sd, "prior": prior}


def _rig(errors=(0.4, 0.5, 0.45), pairs=None, c1=None) -> Rig:
    K = Camera.intrinsics_from_fov(np.radians(50), 200, 150)
    cams = [RigCamera(f"c{i}", 200, 150, K, np.eye(4), {}, e) for i, e in enumerate(errors)]
    pairs = pairs if pairs is not None else [_pair("c0", "c1", 900), _pair("c0", "c2", 800), _pair("c1", "c2", 700)]
    figures = {c.name: _figures() for c in cams}
    figures["c1"] = c1 or figures["c1"]
    return Rig(cams, pairs, checks={"cameras": figures})


def test_a_good_rig_passes():
    assert problems(_rig(), ["c0", "c1", "c2"]) == []
    assert check_rig(_rig(), ["c0", "c1", "c2"], "cap").checks["gate"]["passed"]


@pytest.mark.parametrize("rig, expected, phrase", [
    (_rig(errors=(0.4, 3.2, 0.5)), ["c0", "c1", "c2"], "camera c1 has 3.20 px"),
    (_rig(pairs=[_pair("c0", "c1", 900), _pair("c0", "c2", 40, 30), _pair("c1", "c2", 20, 10)]), ["c0", "c1", "c2"],
     "split the cameras into"),
    (_rig(), ["c0", "c1", "c2", "c3"], "cameras ['c3'] could not be registered"),
    (_rig(c1=_figures(focal_sd=3.0)), ["c0", "c1", "c2"], "camera c1 is not determined by the frames: standard "
                                                           "errors focal 3.0 px (1.9 % of 160.8, at most 1 %)"),
    (_rig(c1=_figures(rotation_sd=0.7)), ["c0", "c1", "c2"], "rotation 0.70 deg (at most 0.5)"),
    (_rig(c1=_figures(centre_sd=0.03)), ["c0", "c1", "c2"], "centre 3.0 % of the rig radius (at most 1 %)"),
    (_rig(c1=_figures(focal_sd=0.5, verdict="contradicts the frames")), ["c0", "c1", "c2"],
     "camera c1: the focal prior 150.0 +- 1.5 px contradicts its frames (160.8 +- 0.5 px)"),
])
def test_the_gate_refuses_with_the_figures(rig, expected, phrase):
    with pytest.raises(InputError) as err:
        check_rig(rig, expected, "cap")
    msg = str(err.value)
    assert "\n" not in msg and phrase in msg and "self-calibration refused" in msg
    assert "c0-c1" in msg and "verified" in msg  # the per-pair figures
    assert "--calibration" in msg and "--focal CAM=PX" in msg  # what to do
    assert "`fixer4d calibrate --write-board board.png`" in msg and "board.json in CAPTURE/board/" in msg


def test_only_the_undetermined_camera_is_named():
    found = problems(_rig(c1=_figures(focal_sd=3.0), errors=(0.4, 0.5, 0.45)), ["c0", "c1", "c2"])
    assert len(found) == 1 and "camera c1 " in found[0]
    assert problems(_rig(c1=_figures(verdict="overruled by the frames")), ["c0", "c1", "c2"]) == []


@pytest.fixture(scope="module")
def grid_capture(tmp_path_factory, capture_writer):
    """Four forward-facing cameras (the demo's 2x2 corners, 200x150, 4 frames) as videos."""
    from fixer4d.scene import load_scene
    from fixer4d.scene.synthetic import builtin_spec_path

    spec = json.loads(builtin_spec_path("demo").read_text())
    spec.update(name="grid4", frames=4)
    spec["rig"].update(rows=2, cols=2, spacing=[0.9, 0.6])
    root = tmp_path_factory.mktemp("grid4")
    (root / "spec.json").write_text(json.dumps(spec))
    scene = load_scene(root / "spec.json")
    capture_writer(scene, root / "capture", list(range(4)))
    return scene, root / "capture"


def test_calibrate_refuses_a_rig_whose_focal_the_frames_cannot_fix(grid_capture, tmp_path, capfd):
    """Parallel cameras fit any focal length (a stretched scene): refused, never written."""
    from fixer4d.cli import main

    _, capture = grid_capture
    assert main(["calibrate", str(capture), "--out", str(tmp_path / "rig.json"), "--quiet"]) == 2
    err = capfd.readouterr().err
    assert "self-calibration refused" in err and "is not determined by the frames" in err and "cam00-cam01" in err
    assert ".cc:" not in err  # COLMAP's own log lines (glog, e.g. "I1127 ... sift.cc:1685]") stay silent under --quiet
    assert not (tmp_path / "rig.json").exists()


def test_a_known_focal_gives_the_grid_its_rotations_and_the_gate_names_its_centres(grid_capture):
    """The true focal as a prior (1 %): the parallel grid's relative rotations come back within
    0.5 degrees; its depth (hence the centres) stays uncertain to more than 1 % of the rig radius,
    and the gate says so camera by camera, with errors within three of its standard errors."""
    from fixer4d.calib.priors import parse_focal_priors
    from fixer4d.calib.sfm import SfMConfig, calibrate_sfm
    from fixer4d.scene.capture import CaptureFiles

    scene, capture = grid_capture
    files = CaptureFiles(capture)
    rig = calibrate_sfm(files, SfMConfig(focal=parse_focal_priors([str(scene.cameras[0].fx)], files.names)),
                        progress=False)
    assert rig.names() == ["cam00", "cam01", "cam02", "cam03"] and len(rig.pairs) == 6
    assert all(c.reprojection_error_px < 0.5 for c in rig.cameras)
    est = [c.camera() for c in rig.cameras]
    for i in range(4):
        for j in range(i + 1, 4):  # the rig's own shape: relative rotations
            rel_est = est[i].R.T @ est[j].R
            rel_gt = scene.cameras[i].R.T @ scene.cameras[j].R
            angle = np.degrees(np.arccos(np.clip((np.trace(rel_est.T @ rel_gt) - 1) / 2, -1, 1)))
            assert angle < 0.5
    figures = rig.checks["cameras"]
    for c, g in zip(rig.cameras, scene.cameras):
        assert abs(c.K[0, 0] - g.fx) < 3 * figures[c.name]["focal_sd_px"]
        assert figures[c.name]["prior"]["verdict"] == "agrees"
    centres = [n for n, f in figures.items() if f["centre_sd_rel"] > MAX_CENTRE_SD_REL]
    assert centres and all(figures[n]["focal_sd_px"] < MAX_FOCAL_SD_REL * figures[n]["focal_px"] for n in centres)
    assert [p.split(" ")[1] for p in problems(rig, files.names)] == centres  # exactly those cameras are named


def test_calibrate_prints_each_cameras_standard_errors_and_the_priors_verdict():
    from fixer4d.cli.calibrate import _uncertainty

    line = _uncertainty({**_figures(focal_sd=2.1), "frames_focal_px": 515.0, "frames_focal_sd_px": 3.0,
                         "prior": {"focal_px": 466.0, "sd_px": 4.7, "verdict": "overruled by the frames"}})
    assert line == ("; standard errors focal 2.1 px, rotation 0.10 deg, centre 0.4 % of the rig radius; focal prior "
                    "466.0 +- 4.7 px overruled by the frames (frames alone: 515.0 +- 3.0 px)")
    assert _uncertainty(None) == ""  # a rig from a board or a file has no such figures
