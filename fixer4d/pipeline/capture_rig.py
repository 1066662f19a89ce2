"""A run on a capture keeps the calibration it uses in the run folder: calibrated there when the
capture has no calibration file, else a copy of the file it was given or found beside the videos."""
from __future__ import annotations

import dataclasses
from pathlib import Path

# The file a run folder keeps its calibration in (the run folder accepts it before its config exists).
RUN_RIG_NAME = "rig.json"


def calibrate_into_run(config, out: str | Path, progress: bool = True):
    """``config`` (a RunConfig) unchanged unless its scene is a capture folder; then the rig the
    run uses is written to ``out``/rig.json and the returned config names it (so RUN/config.json
    records it): the calibration given (--calibration) or found beside the videos, read for the
    capture's cameras and copied (its origin in the rig's ``source``); else calibrated there
    (``fixer4d.calib.calibrate_capture``: from the board videos in CAPTURE/board/ when that holds
    a board.json, else self-calibrated and gated), and reused when it is already there."""
    from fixer4d.calib import calibrate_capture
    from fixer4d.calib.formats import find_calibration, read_calibration
    from fixer4d.calib.rig import read_rig_json
    from fixer4d.scene import detect_layout
    from fixer4d.scene.capture import CaptureFiles

    sc = config.scene
    src = Path(str(sc.source))
    if not src.is_dir() or detect_layout(src) != "capture":
        return config
    path = Path(out) / RUN_RIG_NAME
    frame_range = None if sc.frame_range is None else tuple(sc.frame_range)
    files = CaptureFiles(src, sc.offsets, frame_range)
    given = sc.calibration if sc.calibration is not None else find_calibration(src)
    if given is not None:
        if Path(given).resolve() != path.resolve():
            rig = read_calibration(given, files.names)
            rig.source = f"copied from {Path(given).resolve()} ({rig.source})"
            rig.write(path)
    elif path.is_file():
        read_rig_json(path)  # a damaged file fails here, naming itself
    else:
        calibrate_capture(files, path, progress=progress)
    return dataclasses.replace(config, scene=dataclasses.replace(sc, calibration=str(path.resolve())))
