"""Calibration files in the formats people have, read into a ``Rig`` whose cameras carry the
capture's camera names.

* fixer4d's own rig.json (``fixer4d.calib.rig``);
* a COLMAP sparse model: a folder with cameras/images .bin or .txt (``sparse/0``);
* nerfstudio transforms.json (``transform_matrix`` camera-to-world in OpenGL axes, intrinsics
  ``fl_x fl_y cx cy w h k1 k2 p1 p2 [k3]`` at the top level or per frame);
* LLFF poses_bounds.npy (one row per camera, in sorted camera-name order).

An image of a COLMAP model or a frame of transforms.json names its camera through its path:
``cam01.png``, ``cam01/000000.jpg`` or ``images/cam01_000000.jpg`` all belong to camera "cam01"
(the folder, the stem, or the stem up to its last ``_``/``-``). Several images of one camera are
one pose (the rig is static): the first is used.
"""
from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from fixer4d.calib.rig import Rig, RigCamera, read_rig_json, rig_from_cameras
from fixer4d.errors import InputError
from fixer4d.geometry.camera import CV_TO_GL

# File names looked for beside the videos, in this order.
RIG_NAME = "rig.json"
TRANSFORMS_NAME = "transforms.json"
LLFF_NAME = "poses_bounds.npy"
COLMAP_DIRS = ("sparse/0", "sparse", "colmap/sparse/0", "colmap/sparse", ".")
_COLMAP_FILES = ("cameras.bin", "cameras.txt")
SCALE_IMPORTED = "as in the imported calibration file"


def find_calibration(folder: str | Path) -> Path | None:
    """The calibration file (or COLMAP model folder) in a capture folder, else None."""
    folder = Path(folder)
    for name in (RIG_NAME, TRANSFORMS_NAME, LLFF_NAME):
        if (folder / name).is_file():
            return folder / name
    for sub in COLMAP_DIRS:
        d = folder / sub
        if any((d / f).is_file() for f in _COLMAP_FILES):
            return d.resolve() if sub == "." else d
    return None


def camera_of(path: str, names: list[str]) -> str | None:
    """The camera name among ``names`` that an image path belongs to (see the module doc)."""
    p = Path(str(path).replace("\\", "/"))
    stem = p.stem
    candidates = [p.parent.name, stem, re.split(r"[_\-.](?=[^_\-.]*$)", stem)[0]]
    for c in candidates:
        if c in names:
            return c
    return None


def read_calibration(path: str | Path, names: list[str]) -> Rig:
    """Read any supported calibration and keep the cameras named ``names`` (in that order).

    Raises InputError naming the file when it cannot be read, lacks one of ``names`` or (a rig.json)
    calibrates a camera that ``names`` lacks.
    """
    path = Path(path)
    if not path.exists():
        raise InputError(f"--calibration {path}: no such file or folder")
    through_paths = False  # COLMAP and nerfstudio name a camera through its image paths
    if path.is_dir() or path.name in _COLMAP_FILES or path.name in ("images.bin", "images.txt"):
        rig = read_colmap(path if path.is_dir() else path.parent, names)
        through_paths = True
    elif path.suffix == ".npy":
        rig = read_llff(path, names)
    elif path.suffix == ".json":
        from fixer4d.jsonfile import read_json_object

        data = read_json_object(path, str(path), "pass a rig.json, transforms.json, poses_bounds.npy or COLMAP model")
        through_paths = "frames" in data
        rig = read_transforms(path, names) if through_paths else read_rig_json(path)
    else:
        raise InputError(f"--calibration {path}: unknown calibration format; pass a rig.json, a nerfstudio "
                         f"transforms.json, a poses_bounds.npy or a COLMAP sparse model folder (cameras.bin/images.bin)")
    by_name = rig.by_name()
    missing = [n for n in names if n not in by_name]
    if missing:
        fix = ("name the calibration's images after the capture's videos/folders (e.g. cam01.png or "
               "cam01/000000.jpg)" if through_paths else
               "rename the videos/folders after the calibration's cameras, or the cameras in the calibration "
               "after the videos")
        raise InputError(f"{path}: no camera named {missing} (it has {sorted(by_name)}); {fix}")
    orphans = sorted(set(by_name) - set(names))
    if orphans:
        raise InputError(f"{path}: calibrates cameras {orphans} that have no video or image folder in the capture "
                         f"(its cameras: {names}); a run uses every calibrated camera: add their videos, or remove "
                         f"them from the calibration to run on the {len(names)} cameras there are")
    rig.cameras = [by_name[n] for n in names]
    return rig


def read_colmap(folder: Path, names: list[str]) -> Rig:
    """A COLMAP sparse model folder -> Rig (first image of each capture camera)."""
    from fixer4d.calib.colmap import pycolmap_module, rig_camera_from_colmap

    pycolmap = pycolmap_module()
    if not any((folder / f).is_file() for f in _COLMAP_FILES):
        raise InputError(f"{folder}: not a COLMAP sparse model (no cameras.bin or cameras.txt)")
    try:
        rec = pycolmap.Reconstruction(str(folder))
    except Exception as exc:  # noqa: BLE001 - pycolmap raises plain RuntimeErrors for damaged files
        raise InputError(f"{folder}: cannot read the COLMAP model ({exc}); re-export it from COLMAP") from None
    cams: dict[str, RigCamera] = {}
    for image in sorted(rec.images.values(), key=lambda im: im.name):
        name = camera_of(image.name, names)
        if name is None or name in cams or not image.has_pose:
            continue
        cfw = image.cam_from_world
        cfw = cfw() if callable(cfw) else cfw
        w2c = np.eye(4)
        w2c[:3] = np.asarray(cfw.matrix(), np.float64)
        cams[name] = rig_camera_from_colmap(rec.cameras[image.camera_id], name, w2c, str(folder))
    return Rig([cams[n] for n in names if n in cams], source=f"COLMAP model {folder}", scale=SCALE_IMPORTED)


def read_transforms(path: Path, names: list[str]) -> Rig:
    """nerfstudio transforms.json -> Rig."""
    from fixer4d.jsonfile import read_json_object

    data = read_json_object(path, str(path), "re-export it (nerfstudio ns-process-data)")
    frames = data.get("frames")
    if not isinstance(frames, list) or not frames:
        raise InputError(f"{path}: no 'frames' list; a nerfstudio transforms.json has frames with file_path and "
                         f"transform_matrix")
    cams: dict[str, RigCamera] = {}
    for i, fr in enumerate(frames):
        name = camera_of(str(fr.get("file_path", "")), names)
        if name is None or name in cams:
            continue
        get = lambda key, default=None: fr.get(key, data.get(key, default))  # noqa: E731 - per-frame over global
        try:
            fx, fy = float(get("fl_x")), float(get("fl_y", get("fl_x")))
            w, h = int(get("w")), int(get("h"))
            cx, cy = float(get("cx", w / 2.0)), float(get("cy", h / 2.0))
            c2w_gl = np.asarray(fr["transform_matrix"], np.float64)
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"{path}: frame {i} lacks intrinsics or pose ({exc!r}); each frame needs fl_x, w, h "
                             f"(here or at the top level) and transform_matrix") from None
        model = str(get("camera_model", "OPENCV"))
        if model != "OPENCV":
            raise InputError(f"{path}: camera_model {model} is not supported; use OPENCV (radial-tangential)")
        if c2w_gl.shape == (3, 4):
            c2w_gl = np.vstack([c2w_gl, [0, 0, 0, 1]])
        dist = {k: float(get(k, 0.0)) for k in ("k1", "k2", "p1", "p2", "k3")}
        K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
        cams[name] = RigCamera(name, w, h, K, np.linalg.inv(c2w_gl @ CV_TO_GL), dist)
    return Rig([cams[n] for n in names if n in cams], source=f"nerfstudio {path}", scale=SCALE_IMPORTED)


def read_llff(path: Path, names: list[str]) -> Rig:
    """poses_bounds.npy (rows in sorted camera-name order) -> Rig."""
    from fixer4d.geometry.llff import llff_to_cameras, read_poses_bounds

    pb = read_poses_bounds(path)
    if pb.ndim == 2 and pb.shape[0] != len(names):
        raise InputError(f"{path}: {pb.shape[0]} pose rows for {len(names)} cameras ({names}); poses_bounds.npy "
                         f"needs one row per camera in sorted name order")
    cams, _ = llff_to_cameras(pb, sorted(names), str(path))
    return rig_from_cameras(cams, f"LLFF {path}", SCALE_IMPORTED)
