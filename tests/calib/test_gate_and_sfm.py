"""Self-calibration end to end on a small synthetic capture, and the gate that refuses an
untrustworthy rig in one message (camera, per-pair matches, what to do)."""
from __future__ import annotations

import json

import numpy as np
import pytest

from fixer4d.calib.gate import check_rig, problems
from fixer4d.calib.rig import Rig, RigCamera
from fixer4d.errors import InputError
from fixer4d.geometry.camera import Camera


def _pair(a, b, verified, shared=300):
    return {"cameras": [a, b], "raw_matches": verified + 50, "verified_matches": verified, "shared_points": shared}


def _rig(errors=(0.4, 0.5, 0.45), pairs=None, sensitivity=1.0) -> Rig:
    K = Camera.intrinsics_from_fov(np.radians(50), 200, 150)
    cams = [RigCamera(f"c{i}", 200, 150, K, np.eye(4), {}, e) for i, e in enumerate(errors)]
    pairs = pairs if pairs is not None else [_pair("c0", "c1", 900), _pair("c0", "c2", 800), _pair("c1", "c2", 700)]
    return Rig(cams, pairs, checks={"focal_sensitivity_px": sensitivity})


def test_a_good_rig_passes():
    assert problems(_rig(), ["c0", "c1", "c2"]) == []
    assert check_rig(_rig(), ["c0", "c1", "c2"], "cap").checks["gate"]["passed"]


@pytest.mark.parametrize("rig, expected, phrase", [
    (_rig(errors=(0.4, 3.2, 0.5)), ["c0", "c1", "c2"], "camera c1 has 3.20 px"),
    (_rig(pairs=[_pair("c0", "c1", 900), _pair("c0", "c2", 40, 30), _pair("c1", "c2", 20, 10)]), ["c0", "c1", "c2"],
     "split the cameras into"),
    (_rig(), ["c0", "c1", "c2", "c3"], "cameras ['c3'] could not be registered"),
    (_rig(sensitivity=0.01), ["c0", "c1", "c2"], "do not determine the focal length"),
])
def test_the_gate_refuses_with_the_figures(rig, expected, phrase):
    with pytest.raises(InputError) as err:
        check_rig(rig, expected, "cap")
    msg = str(err.value)
    assert "\n" not in msg and phrase in msg and "self-calibration refused" in msg
    assert "c0-c1" in msg and "verified" in msg  # the per-pair figures
    assert "--calibration" in msg and "--focal" in msg  # what to do
    assert "`fixer4d calibrate --write-board board.png`" in msg and "board.json in CAPTURE/board/" in msg


def test_focal_given_skips_the_focal_check():
    assert problems(_rig(sensitivity=0.0), ["c0", "c1", "c2"], focal_given=True) == []


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


def test_calibrate_refuses_a_rig_whose_focal_the_frames_cannot_fix(grid_capture, tmp_path, capsys):
    """Parallel cameras fit any focal length (a stretched scene): refused, never written."""
    from fixer4d.cli import main

    _, capture = grid_capture
    assert main(["calibrate", str(capture), "--out", str(tmp_path / "rig.json"), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "self-calibration refused" in err and "focal length" in err and "cam00-cam01" in err
    assert not (tmp_path / "rig.json").exists()


def test_calibrate_with_a_known_focal_recovers_the_rig(grid_capture, tmp_path):
    from fixer4d.cli import main
    from fixer4d.init.poses import compare_poses
    from fixer4d.scene import load_scene

    scene, capture = grid_capture
    out = tmp_path / "rig.json"
    assert main(["calibrate", str(capture), "--out", str(out), "--quiet", "--focal", str(scene.cameras[0].fx)]) == 0
    rig = json.loads(out.read_text())
    assert [c["name"] for c in rig["cameras"]] == ["cam00", "cam01", "cam02", "cam03"] and len(rig["pairs"]) == 6
    assert all(c["reprojection_error_px"] < 0.5 for c in rig["cameras"])
    cap = load_scene(capture, calibration=out)
    err = compare_poses(cap.cameras, scene.cameras)
    assert err["rotation_deg_max"] < 2.0 and err["center_error_rel_max"] < 0.03
    for i in range(4):
        for j in range(i + 1, 4):  # the rig's own shape: relative rotations
            rel_est = cap.cameras[i].R.T @ cap.cameras[j].R
            rel_gt = scene.cameras[i].R.T @ scene.cameras[j].R
            angle = np.degrees(np.arccos(np.clip((np.trace(rel_est.T @ rel_gt) - 1) / 2, -1, 1)))
            assert angle < 0.5
