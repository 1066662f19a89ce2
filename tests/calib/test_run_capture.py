"""`fixer4d run` on a capture: calibration found, given or refused before anything is written;
the report of a run without a held-out camera says so."""
from __future__ import annotations

import dataclasses

import numpy as np
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


def test_the_no_held_out_report_speaks_of_train_views_and_their_response(tmp_path):
    from fixer4d.pipeline import report as R

    metrics = {"held_out": False, "mean": {"psnr": 31.0, "dssim1": 0.1, "dssim2": 0.05, "lpips": None}}
    rows = [{**R.metrics_row(R.ROW_FULL, metrics, 12.0), "unobserved_fraction": 0.02}]
    model = {"camera_response": {"views": [{"gain": [1.1, 1.0, 0.9]}, {"gain": [0.9, 1.0, 1.1]}]},
             "reasons": {"camera_response": "measured"}}
    R.write_report(tmp_path, "cap: 2 cameras (2 train, no held-out camera)", rows, {"stage1": 1.0}, {"model": model})
    text = (tmp_path / "report.md").read_text()
    assert "through the colour response its camera trained" in text
    assert "held-out pixels" not in text and "over the train-view pixels" in text


class _GainedScene:
    """The tiny scene's train cameras as a capture with no held-out camera whose cameras record
    the scene's colours times a per-camera RGB gain (real rigs expose and white-balance each
    camera on its own)."""

    def __init__(self, scene, gains: np.ndarray) -> None:
        self._scene, self.gains = scene, gains
        self.train_ids, self.test_ids = list(scene.train_ids), []

    def __getattr__(self, name):
        return getattr(self._scene, name)

    def frame(self, f: int, cam: int) -> np.ndarray:
        return np.clip(self._scene.frame(f, cam) * self.gains[self.train_ids.index(cam)], 0, 1).astype(np.float32)


def test_the_train_view_fit_scores_each_camera_through_its_trained_response(tmp_path, tiny_scene):
    """A model that keeps the rig's mean colour and trained each camera's gain ranks above a
    blurrier one that baked each camera's colour in, once each view is scored through its response
    (the issue's no-held-out report ranked the dense model below the sparse baseline)."""
    import cv2
    import torch

    from fixer4d.eval.evaluate import evaluate
    from fixer4d.model.camera_response import CameraResponse, train_view_render_fn

    gains = np.array([[1.25, 1.0, 0.8], [0.8, 1.0, 1.25], [1.1, 0.9, 1.0], [0.9, 1.1, 1.0]])[:len(tiny_scene.train_ids)]
    gains /= np.exp(np.log(gains).mean(0))  # the rig's mean response is the identity (CameraResponse)
    scene = _GainedScene(tiny_scene, gains)
    index = {c.name: i for i, c in enumerate(tiny_scene.cameras)}

    def dense(camera, t):  # the rig's mean colours, exactly
        return tiny_scene.frame(int(round(t * tiny_scene.num_frames)), index[camera.name])

    def baseline(camera, t):  # each camera's own colours, blurred
        return cv2.GaussianBlur(scene.frame(int(round(t * tiny_scene.num_frames)), index[camera.name]), (0, 0), 0.5)

    response = CameraResponse(len(gains))
    with torch.no_grad():
        response.log_gain.copy_(torch.tensor(np.log(gains), dtype=torch.float32))
    train = [tiny_scene.cameras[i] for i in scene.train_ids]
    score = {name: evaluate(fn, scene, tmp_path / name, save_examples=0, progress=False)["mean"]["psnr"]
             for name, fn in (("raw", dense), ("baseline", baseline),
                              ("response", train_view_render_fn(dense, response, train)))}
    assert score["raw"] < score["baseline"] < score["response"]


def test_the_self_check_line_names_cameras_by_name():
    from fixer4d.pipeline.report import self_check_line

    check = {"decision": "skip", "held_back_camera": 2, "fold_cameras": [0, 1, 3], "held_back_name": "cam18",
             "fold_names": ["cam01", "cam09", "cam23"], "scale": 0.5, "psnr": {"skip": 25.0, "continue": 24.9,
                                                                             "refine": 24.8}}
    line = self_check_line(check)
    assert "held-back train camera cam18 (fold of cameras cam01, cam09, cam23 at scale 0.5" in line
