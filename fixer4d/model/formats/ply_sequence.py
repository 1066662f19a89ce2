"""A spacetime model as a folder of per-frame 3DGS PLYs (``ply3dgs``) plus ``manifest.json``.

    DIR/frame_00000.ply ... frame_<F-1>.ply   one static 3DGS model per frame
    DIR/manifest.json                         {"format", "version", "fps", "frame_count",
                                               "frames": [file names], "times": [clip times],
                                               "gaussians": [rows per frame], "min_opacity"}

Frames are produced and written one at a time (memory holds one frame's rows), into a
temporary folder that replaces DIR only once every frame and the manifest are on disk.
"""
from __future__ import annotations

from pathlib import Path
from typing import Callable, Sequence

from fixer4d.atomic import atomic_dir, write_json
from fixer4d.errors import InputError
from fixer4d.model.formats.ply3dgs import write_frame
from fixer4d.model.spacetime import SpacetimeGaussians

FORMAT = "fixer4d-ply-sequence"
VERSION = 1
MANIFEST = "manifest.json"
FRAME_PATTERN = "frame_{:05d}.ply"


def check_output_folder(out: Path, owned: Callable[[Path], bool]) -> None:
    """Refuse to replace a folder that holds files this writer did not write (``owned``)."""
    if out.exists() and not out.is_dir():
        raise InputError(f"--out {out}: is a file; pass a folder for a frame sequence")
    if out.is_dir():
        foreign = [p.name for p in out.iterdir() if not owned(p)]
        if foreign:
            raise InputError(f"--out {out}: folder holds other files ({', '.join(sorted(foreign)[:3])}"
                             f"{', ...' if len(foreign) > 3 else ''}); choose a new or empty folder")


def _is_sequence_file(p: Path) -> bool:
    return p.name == MANIFEST or (p.name.startswith("frame_") and p.suffix == ".ply")


def export_ply_sequence(model: SpacetimeGaussians, out: str | Path, times: Sequence[float], *, fps: float,
                        min_opacity: float, progress: Callable[[int, int], None] | None = None) -> Path:
    """Write ``model`` at each clip time in ``times`` as DIR/frame_XXXXX.ply and DIR/manifest.json.

    min_opacity: rows whose opacity at the frame's time is below it are left out (the export CLI
    passes the rasterizers' smallest blended alpha). progress(done, total) after each frame.
    Returns the manifest path. An existing DIR is replaced only if it holds nothing but a
    previous sequence.
    """
    out = Path(out)
    times = [float(t) for t in times]
    if not times:
        raise InputError("a PLY sequence needs at least one frame")
    if not fps > 0:
        raise InputError(f"fps must be > 0, got {fps}")
    check_output_folder(out, _is_sequence_file)
    names, counts = [], []
    with atomic_dir(out) as tmp:
        for k, t in enumerate(times):
            name = FRAME_PATTERN.format(k)
            counts.append(write_frame(model, t, tmp / name, min_opacity))
            names.append(name)
            if progress is not None:
                progress(k + 1, len(times))
        write_json(tmp / MANIFEST, {"format": FORMAT, "version": VERSION, "convention": "3dgs-ply",
                                    "fps": float(fps), "frame_count": len(names), "frames": names,
                                    "times": times, "gaussians": counts, "min_opacity": float(min_opacity)})
    return out / MANIFEST
