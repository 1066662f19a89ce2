"""`fixer4d run` on a capture: calibration found, given or refused before anything is written;
the report of a run without a held-out camera says so."""
from __future__ import annotations

import dataclasses

import pytest

from fixer4d.calib.rig import Rig, RigCamera
from fixer4d.errors import InputError
from fixer4d.pipeline.capture_rig import calibrate_into_run
from fixer4d.pipeline.config import RunConfig


def _config(source, **scene) -> RunConfig:
    cfg = RunConfig()
    return dataclasses.replace(cfg, scene=dataclasses.replace(cfg.scene, source=str(source), **scene))


def test_the_calibration_beside_the_videos_is_recorded_and_copied_into_the_run(tmp_path, tiny4, capture_writer):
    from fixer4d.calib.rig import read_rig_json

    scene, ids = tiny4
    capture_writer(scene, tmp_path / "cap", ids)
    Rig([RigCamera(scene.cameras[i].name, 64, 48, scene.cameras[i].K, scene.cameras[i].w2c) for i in ids]).write(
        tmp_path / "cap" / "rig.json")
    cfg = calibrate_into_run(_config(tmp_path / "cap"), tmp_path / "run", progress=False)
    assert cfg.scene.calibration == str((tmp_path / "run" / "rig.json").resolve())
    copied = read_rig_json(tmp_path / "run" / "rig.json")
    assert copied.names() == sorted(scene.cameras[i].name for i in ids)
    assert f"copied from {(tmp_path / 'cap' / 'rig.json').resolve()}" in copied.source
    other = _config("demo")
    assert calibrate_into_run(other, tmp_path / "run", progress=False) is other


def test_an_untrustworthy_self_calibration_stops_the_run_before_it_writes(tmp_path, tiny4, capture_writer):
    scene, ids = tiny4
    capture_writer(scene, tmp_path / "cap", ids)  # 64x48 frames: too few features to calibrate on
    with pytest.raises(InputError, match="self-calibration refused"):
        calibrate_into_run(_config(tmp_path / "cap"), tmp_path / "run", progress=False)
    assert not (tmp_path / "run" / "rig.json").exists()


def test_report_of_a_run_without_held_out_camera(tmp_path):
    from fixer4d.pipeline import report as R

    metrics = {"held_out": False, "mean": {"psnr": 31.0, "dssim1": 0.1, "dssim2": 0.05, "lpips": None}}
    row = R.metrics_row(R.ROW_FULL, metrics, 12.0)
    assert row["held_out"] is False
    R.write_report(tmp_path, "cap: 4 cameras (4 train, no held-out camera)", [row], {"stage1": 1.0})
    text = (tmp_path / "report.md").read_text()
    assert "No held-out camera" in text and "fit to the train views" in text and "31.00" in text
    held = R.metrics_row(R.ROW_FULL, {**metrics, "held_out": True}, 12.0)
    assert "held_out" not in held
