"""LLFF's poses_bounds.npy: camera poses and intrinsics as one row of 17 numbers per camera.

A row is a 3x5 matrix [R | t | hwf] row-major (R's columns are the camera's down, right and
backward axes in world, t its centre, hwf = image height, width and focal length in pixels) then
the near and far scene depths. Neural3DV scenes carry it (``fixer4d.scene.n3dv``), a capture may
bring it as its calibration (``fixer4d.calib.formats``), and ``fixer4d make-scene`` writes it.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from fixer4d.errors import InputError
from fixer4d.geometry.camera import Camera

# LLFF stores one focal length and a centred principal point; intrinsics that differ from that by
# more than this (pixels, or relative for fx vs fy) cannot be written without loss.
LLFF_PRINCIPAL_TOL_PX = 1e-6
LLFF_FOCAL_RTOL = 1e-9


def llff_to_cameras(poses_bounds: np.ndarray, names: list[str] | None = None,
                    source: str = "poses_bounds.npy") -> tuple[list[Camera], np.ndarray]:
    """(N, 17) LLFF rows -> (cameras at the hwf resolution, near/far (N, 2))."""
    pb = np.asarray(poses_bounds, dtype=np.float64)
    if pb.ndim != 2 or pb.shape[1] != 17:
        raise InputError(f"{source}: expected an (N, 17) array (3x5 pose + near, far per camera), got shape "
                         f"{pb.shape}; regenerate it with LLFF's imgs2poses or `fixer4d make-scene`")
    bad = np.nonzero(~np.all(np.isfinite(pb), axis=1))[0]
    if bad.size:
        raise InputError(f"{source}: non-finite values (NaN/inf) in rows {bad.tolist()}; "
                         f"recompute those camera poses (e.g. rerun COLMAP/imgs2poses)")
    cams = []
    for i, row in enumerate(pb):
        m = row[:15].reshape(3, 5)
        h, w, f = m[:, 4]
        if h <= 0 or w <= 0 or f <= 0:
            raise InputError(f"{source}: row {i} has a non-positive image size or focal (h, w, f = {h}, {w}, {f})")
        c2w = np.eye(4)
        c2w[:3, 0] = m[:, 1]   # right
        c2w[:3, 1] = m[:, 0]   # down
        c2w[:3, 2] = -m[:, 2]  # forward = -backward
        c2w[:3, 3] = m[:, 3]
        K = np.array([[f, 0.0, w / 2.0], [0.0, f, h / 2.0], [0.0, 0.0, 1.0]])
        name = names[i] if names is not None else f"cam{i:02d}"
        cams.append(Camera(K, c2w, int(round(w)), int(round(h)), name))
    return cams, pb[:, 15:17].copy()


def llff_compatible(cam: Camera) -> bool:
    """Whether LLFF's poses_bounds can store ``cam``: square pixels, centred principal point, no skew."""
    return not (abs(cam.fx - cam.fy) > LLFF_FOCAL_RTOL * cam.fx or abs(cam.cx - cam.width / 2) > LLFF_PRINCIPAL_TOL_PX
                or abs(cam.cy - cam.height / 2) > LLFF_PRINCIPAL_TOL_PX or abs(cam.K[0, 1]) > 0)


def cameras_to_llff(cameras: list[Camera], near_far: np.ndarray) -> np.ndarray:
    """Cameras (square pixels, centred principal point) + near/far ((2,) or (N, 2)) -> (N, 17)."""
    nf = np.broadcast_to(np.asarray(near_far, np.float64), (len(cameras), 2))
    rows = []
    for cam in cameras:
        if not llff_compatible(cam):
            raise InputError(f"camera {cam.name}: LLFF poses_bounds stores one focal and a centred principal point; "
                             f"this camera has fx={cam.fx}, fy={cam.fy}, cx={cam.cx}, cy={cam.cy}: "
                             f"undistort/crop the images to a centred square-pixel camera first")
        m = np.empty((3, 5))
        m[:, 0] = cam.c2w[:3, 1]
        m[:, 1] = cam.c2w[:3, 0]
        m[:, 2] = -cam.c2w[:3, 2]
        m[:, 3] = cam.c2w[:3, 3]
        m[:, 4] = [cam.height, cam.width, cam.fx]
        rows.append(m.reshape(-1))
    return np.concatenate([np.stack(rows), nf], 1)


def read_poses_bounds(path: str | Path) -> np.ndarray:
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: file not found; a Neural3DV scene needs poses_bounds.npy next to its camXX.mp4")
    try:
        return np.load(path, allow_pickle=False)
    except (ValueError, OSError) as exc:
        raise InputError(f"{path}: not a readable .npy array ({exc}); regenerate poses_bounds.npy") from None
