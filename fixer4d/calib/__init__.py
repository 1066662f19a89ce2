"""fixer4d.calib: the rig of a capture, from a calibration file or from the capture's own frames.

``resolve_rig(files, calibration)`` is what opening a capture calls: an explicit calibration
file, else one found beside the videos (``formats.find_calibration``), else a self-calibration
(``sfm.calibrate_sfm`` checked by ``gate.check_rig``) cached per capture under the user's cache
folder, so a viewer or a second run does not repeat it. ``calibrate`` is `fixer4d calibrate`.
"""
from __future__ import annotations

import hashlib
import os
from pathlib import Path
from typing import TYPE_CHECKING

from fixer4d.errors import InputError

if TYPE_CHECKING:  # the package is imported by fixer4d.scene.capture (through calib.rig): no module-level cycle
    from fixer4d.calib.rig import Rig
    from fixer4d.scene.capture import CaptureFiles

__all__ = ["calibrate", "resolve_rig", "cache_path"]


def calibrate(files: "CaptureFiles", out: str | Path | None = None, *, config=None, progress: bool = True) -> "Rig":
    """Self-calibrate a capture, gate the result, write it to ``out`` (rig.json) when given.

    Raises InputError from the gate (naming the camera, the per-pair matches and the fix) when
    the rig is not trustworthy; nothing is written then.
    """
    from fixer4d.calib.gate import check_rig
    from fixer4d.calib.sfm import SfMConfig, calibrate_sfm

    config = config or SfMConfig()
    rig = calibrate_sfm(files, config, progress=progress)
    check_rig(rig, files.names, str(files.root), focal_given=config.focal is not None)
    if out is not None:
        rig.write(out)
    return rig


def cache_path(files: "CaptureFiles") -> Path:
    """Where the self-calibration of this capture is cached: keyed by the files (path, size,
    modification time) and the offsets, under $XDG_CACHE_HOME (default ~/.cache)/fixer4d/calibration."""
    h = hashlib.sha256()
    for s in files.sources:
        for p in (s.images[:1] + s.images[-1:]) if s.images else (s.path,):
            st = p.stat()
            h.update(f"{p.resolve()}|{st.st_size}|{st.st_mtime_ns}|{s.num_frames}\n".encode())
    h.update(repr(sorted(files.offsets.items())).encode())
    base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return base / "fixer4d" / "calibration" / f"{files.root.name}-{h.hexdigest()[:16]}" / "rig.json"


def resolve_rig(files: "CaptureFiles", calibration: str | Path | None = None,
                progress: bool = True) -> tuple["Rig", str]:
    """(rig, where it came from) for a capture; see the module doc for the order."""
    from fixer4d.calib.formats import find_calibration, read_calibration
    from fixer4d.calib.rig import read_rig_json

    if calibration is not None:
        return read_calibration(calibration, files.names), str(calibration)
    found = find_calibration(files.root)
    if found is not None:
        return read_calibration(found, files.names), str(found)
    cached = cache_path(files)
    if cached.is_file():
        try:
            return read_calibration(cached, files.names), f"{cached} (self-calibrated)"
        except InputError:
            pass  # a damaged cache entry is recomputed below
    if progress:
        print(f"[fixer4d] {files.root}: no calibration file; calibrating the rig from its frames "
              f"(cached in {cached.parent})", flush=True)
    rig = calibrate(files, cached, progress=progress)
    return read_rig_json(cached) if cached.is_file() else rig, f"{cached} (self-calibrated)"
