"""A run on a capture without a calibration file calibrates the rig first, into the run folder."""
from __future__ import annotations

import dataclasses
from pathlib import Path

# The file a run folder keeps its calibration in (the run folder accepts it before its config exists).
RUN_RIG_NAME = "rig.json"


def calibrate_into_run(config, out: str | Path, progress: bool = True):
    """``config`` (a RunConfig) unchanged unless its scene is a capture folder with no calibration
    given and none beside the videos: then the rig is calibrated into ``out``/rig.json
    (``fixer4d.calib.calibrate_capture``: from the board videos in CAPTURE/board/ when that holds
    a board.json, else self-calibrated and gated); reused when it is already there, and the
    returned config names it."""
    from fixer4d.calib import calibrate_capture
    from fixer4d.calib.formats import find_calibration
    from fixer4d.calib.rig import read_rig_json
    from fixer4d.scene import detect_layout
    from fixer4d.scene.capture import CaptureFiles

    sc = config.scene
    src = Path(str(sc.source))
    if sc.calibration is not None or not src.is_dir() or detect_layout(src) != "capture" or find_calibration(src):
        return config
    path = Path(out) / RUN_RIG_NAME
    if path.is_file():
        read_rig_json(path)  # a damaged file fails here, naming itself
    else:
        frame_range = None if sc.frame_range is None else tuple(sc.frame_range)
        calibrate_capture(CaptureFiles(src, sc.offsets, frame_range), path, progress=progress)
    return dataclasses.replace(config, scene=dataclasses.replace(sc, calibration=str(path.resolve())))
