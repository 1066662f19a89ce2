"""fixer4d.calib: the rig of a capture, from a calibration file, a filmed board or the capture's own frames.

``resolve_rig(files, calibration)`` is what opening a capture calls (the viewer, `fixer4d init`):
an explicit calibration file, else one found beside the videos (``formats.find_calibration``),
else ``calibrate_capture`` cached per capture under the user's cache folder, so a viewer or a
second run does not repeat it. ``calibrate_capture`` is the one calibration of a capture without
a calibration file (also `fixer4d run`'s, into its run folder: ``fixer4d.pipeline.capture_rig``): from
the board videos in CAPTURE/board/ when that holds a board.json (``board.find_board``), else a
self-calibration (``sfm.calibrate_sfm`` checked by ``gate.check_rig``). ``calibrate`` is the
self-calibration of `fixer4d calibrate`.
"""
from __future__ import annotations

import hashlib
import os
from pathlib import Path
from typing import TYPE_CHECKING

from fixer4d.errors import InputError

if TYPE_CHECKING:  # scene imports calib, never the other way
    from fixer4d.calib.rig import Rig
    from fixer4d.scene.capture import CaptureFiles

__all__ = ["calibrate", "calibrate_capture", "resolve_rig", "cache_path"]


def calibrate(files: "CaptureFiles", out: str | Path | None = None, *, config=None, progress: bool = True) -> "Rig":
    """Self-calibrate a capture, gate the result, write it to ``out`` (rig.json) when given.

    Raises InputError from the gate (naming the camera, the per-pair matches and the fix) when
    the rig is not trustworthy; nothing is written then.
    """
    from fixer4d.calib.gate import check_rig
    from fixer4d.calib.sfm import SfMConfig, calibrate_sfm

    config = config or SfMConfig()
    rig = calibrate_sfm(files, config, progress=progress)
    check_rig(rig, files.names, str(files.root))
    if out is not None:
        rig.write(out)
    return rig


def _origin(board_folder: Path | None) -> str:
    """How ``calibrate_capture`` calibrates a capture, for messages and rig labels."""
    return f"from the board videos in {board_folder}" if board_folder is not None else "from its frames"


def calibrate_capture(files: "CaptureFiles", out: str | Path, progress: bool = True) -> "Rig":
    """Calibrate a capture that has no calibration file and write the rig to ``out`` (rig.json):
    from the board videos in ``files.root``/board/ when it holds a board.json (their own frames,
    no offsets or frame range: those are the scene videos'), else self-calibrated and gated.

    Returns the rig as written (read back from ``out``). Raises InputError (the board's or the
    gate's refusal, one line with what to do) when the rig is not trustworthy; nothing is written then.
    """
    from fixer4d.calib.board import find_board
    from fixer4d.calib.board_calib import calibrate_board
    from fixer4d.calib.rig import read_rig_json

    board = find_board(files.root)
    if progress:
        print(f"[fixer4d] {files.root}: no calibration file; calibrating the rig "
              f"{_origin(board[0] if board else None)} -> {out}", flush=True)
    if board:
        board_files = type(files)(board[0])  # the board videos, opened as a capture like ``files`` (calib never imports scene)
        calibrate_board(board_files, board[1], files.names, progress=progress).write(out)
    else:
        calibrate(files, out, progress=progress)
    return read_rig_json(out)


def _hash_board(h, board_folder: Path) -> None:
    """Adds the board videos (each entry of CAPTURE/board/: name, size, modification time; a
    folder's time changes when its images do) to ``h``, so a cache entry follows the board."""
    for p in sorted(board_folder.iterdir()):
        st = p.stat()
        h.update(f"board|{p.name}|{st.st_size}|{st.st_mtime_ns}\n".encode())


def cache_path(files: "CaptureFiles") -> Path:
    """Where ``calibrate_capture``'s rig of this capture is cached: keyed by the files (path, size,
    modification time), the offsets and the board videos when there are any, under
    $XDG_CACHE_HOME (default ~/.cache)/fixer4d/calibration."""
    from fixer4d.calib.board import BOARD_FOLDER, BOARD_JSON

    h = hashlib.sha256()
    for s in files.sources:
        for p in (s.images[:1] + s.images[-1:]) if s.images else (s.path,):
            st = p.stat()
            h.update(f"{p.resolve()}|{st.st_size}|{st.st_mtime_ns}|{s.num_frames}\n".encode())
    h.update(repr(sorted(files.offsets.items())).encode())
    if (files.root / BOARD_FOLDER / BOARD_JSON).is_file():
        _hash_board(h, files.root / BOARD_FOLDER)
    base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return base / "fixer4d" / "calibration" / f"{files.root.name}-{h.hexdigest()[:16]}" / "rig.json"


def resolve_rig(files: "CaptureFiles", calibration: str | Path | None = None,
                progress: bool = True) -> tuple["Rig", str]:
    """(rig, where it came from) for a capture; see the module doc for the order."""
    from fixer4d.calib.board import find_board
    from fixer4d.calib.formats import find_calibration, read_calibration

    if calibration is not None:
        return read_calibration(calibration, files.names), str(calibration)
    found = find_calibration(files.root)
    if found is not None:
        return read_calibration(found, files.names), str(found)
    cached = cache_path(files)
    board = find_board(files.root)
    label = f"{cached} (calibrated {_origin(board[0] if board else None)})"
    if cached.is_file():
        try:
            return read_calibration(cached, files.names), label
        except InputError:
            pass  # a damaged cache entry is recomputed below
    return calibrate_capture(files, cached, progress=progress), label
