"""A calibrated static rig: per-camera intrinsics, lens distortion and pose; rig.json on disk.

rig.json (written by ``fixer4d calibrate``, read back by every capture)::

    {"format": "fixer4d-rig", "version": 1,
     "cameras": [{"name": "cam01", "width": 640, "height": 360, "K": 3x3 pixels,
                  "distortion": {"k1", "k2", "p1", "p2", "k3"} (OpenCV's radial-tangential model),
                  "w2c": 4x4 world-to-camera (OpenCV axes), "reprojection_error_px": float | null}, ...],
     "pairs": [{"cameras": [a, b], "raw_matches", "verified_matches", "shared_points"}, ...],
     "frames_used": [frame numbers of the capture the calibration looked at],
     "scale": how the world unit was fixed, "source": what produced it}

Pixel convention: K follows ``fixer4d.geometry.camera`` (pixel (u, v) has its centre at
(u + 0.5, v + 0.5)); OpenCV's remap functions put it at (u, v), so ``opencv_K`` shifts by half a
pixel. Frames are undistorted onto the same K and size: downstream code sees a pinhole camera.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from fixer4d import atomic
from fixer4d.errors import InputError
from fixer4d.geometry.camera import Camera

RIG_FORMAT = "fixer4d-rig"
RIG_VERSION = 1
DISTORTION_KEYS = ("k1", "k2", "p1", "p2", "k3")
# Coefficients this small move no pixel of a 4K frame by 1e-3 px: the camera is treated as pinhole.
NEGLIGIBLE_DISTORTION = 1e-9


@dataclass
class RigCamera:
    """One camera of a rig. K (3, 3) pixels at width x height; w2c (4, 4) OpenCV axes;
    distortion: OpenCV radial-tangential coefficients (missing keys are 0)."""

    name: str
    width: int
    height: int
    K: np.ndarray
    w2c: np.ndarray
    distortion: dict[str, float] = field(default_factory=dict)
    reprojection_error_px: float | None = None

    def __post_init__(self) -> None:
        self.K = np.asarray(self.K, np.float64).reshape(3, 3)
        self.w2c = np.asarray(self.w2c, np.float64)
        if self.w2c.shape == (3, 4):
            self.w2c = np.vstack([self.w2c, [0.0, 0.0, 0.0, 1.0]])
        unknown = sorted(set(self.distortion) - set(DISTORTION_KEYS))
        if unknown:
            raise InputError(f"camera {self.name!r}: unknown distortion coefficients {unknown}; "
                             f"use OpenCV's {list(DISTORTION_KEYS)}")
        self.distortion = {k: float(self.distortion.get(k, 0.0)) for k in DISTORTION_KEYS}

    @property
    def coefficients(self) -> np.ndarray:
        """(5,) OpenCV order k1, k2, p1, p2, k3."""
        return np.array([self.distortion[k] for k in DISTORTION_KEYS], np.float64)

    @property
    def is_pinhole(self) -> bool:
        return bool(np.all(np.abs(self.coefficients) < NEGLIGIBLE_DISTORTION))

    def camera(self) -> Camera:
        """The undistorted pinhole camera (same K and size) that downstream code uses."""
        return Camera(self.K, np.linalg.inv(self.w2c), self.width, self.height, self.name)

    def resized(self, width: int, height: int) -> "RigCamera":
        """The same camera for frames of (width, height): K scales with the image; distortion
        coefficients act on normalised coordinates and stay."""
        K = self.K.copy()
        K[0] *= width / self.width
        K[1] *= height / self.height
        return RigCamera(self.name, width, height, K, self.w2c, dict(self.distortion), self.reprojection_error_px)

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "width": int(self.width), "height": int(self.height), "K": self.K.tolist(),
                "distortion": dict(self.distortion), "w2c": self.w2c.tolist(),
                "reprojection_error_px": None if self.reprojection_error_px is None else float(self.reprojection_error_px)}


@dataclass
class Rig:
    """A calibrated rig: cameras plus how the calibration was obtained (pairs, frames, scale)."""

    cameras: list[RigCamera]
    pairs: list[dict[str, Any]] = field(default_factory=list)
    frames_used: list[int] = field(default_factory=list)
    scale: str = "unknown"
    source: str = ""
    checks: dict[str, Any] = field(default_factory=dict)  # what the gate measured (fixer4d.calib.gate)

    def names(self) -> list[str]:
        return [c.name for c in self.cameras]

    def by_name(self) -> dict[str, RigCamera]:
        return {c.name: c for c in self.cameras}

    def to_dict(self) -> dict[str, Any]:
        return {"format": RIG_FORMAT, "version": RIG_VERSION, "cameras": [c.to_dict() for c in self.cameras],
                "pairs": self.pairs, "frames_used": [int(f) for f in self.frames_used], "scale": self.scale,
                "source": self.source, "checks": self.checks}

    def write(self, path: str | Path) -> Path:
        """rig.json, atomically."""
        return atomic.write_json(Path(path), self.to_dict())


def rig_from_cameras(cameras: list[Camera], source: str, scale: str) -> Rig:
    """A distortion-free rig from pinhole cameras (imports of formats that carry no distortion)."""
    return Rig([RigCamera(c.name, c.width, c.height, c.K, c.w2c) for c in cameras], source=source, scale=scale)


def read_rig_json(path: str | Path) -> Rig:
    """Read fixer4d's rig.json; InputError naming the file and the bad entry."""
    from fixer4d.jsonfile import read_json_object

    path = Path(path)
    fix = "rewrite it with `fixer4d calibrate CAPTURE --out rig.json`"
    data = read_json_object(path, str(path), fix)
    cams = data.get("cameras")
    if not isinstance(cams, list) or not cams:
        raise InputError(f"{path}: no 'cameras' list; {fix}")
    out = []
    for i, c in enumerate(cams):
        try:
            cam = RigCamera(str(c["name"]), int(c["width"]), int(c["height"]), np.asarray(c["K"], np.float64),
                            np.asarray(c["w2c"], np.float64), dict(c.get("distortion") or {}),
                            c.get("reprojection_error_px"))
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"{path}: camera entry {i} is malformed ({exc!r}); each needs name, width, height, "
                             f"K (3x3), w2c (4x4); {fix}") from None
        if cam.K.shape != (3, 3) or cam.w2c.shape != (4, 4) or not (np.all(np.isfinite(cam.K)) and np.all(np.isfinite(cam.w2c))):
            raise InputError(f"{path}: camera {cam.name!r} has a malformed or non-finite K (3x3) / w2c (4x4); {fix}")
        out.append(cam)
    return Rig(out, list(data.get("pairs") or []), [int(f) for f in data.get("frames_used") or []],
               str(data.get("scale", "unknown")), str(data.get("source", str(path))), dict(data.get("checks") or {}))


# ---- undistortion -------------------------------------------------------------------------------
def opencv_K(K: np.ndarray) -> np.ndarray:
    """K in OpenCV's pixel convention (pixel centres at integers): the principal point moves by -0.5."""
    Kc = np.array(K, np.float64)
    Kc[0, 2] -= 0.5
    Kc[1, 2] -= 0.5
    return Kc


def undistort_maps(cam: RigCamera) -> tuple[np.ndarray, np.ndarray] | None:
    """cv2.remap maps ((H, W) float32 x and y) that undistort a frame of ``cam`` onto the pinhole
    camera with the same K and size; None for a camera without distortion."""
    import cv2

    if cam.is_pinhole:
        return None
    Kc = opencv_K(cam.K)
    return cv2.initUndistortRectifyMap(Kc, cam.coefficients, None, Kc, (cam.width, cam.height), cv2.CV_32FC1)


def undistort(image: np.ndarray, maps: tuple[np.ndarray, np.ndarray] | None) -> np.ndarray:
    """Apply ``undistort_maps`` to an (H, W, C) image (bilinear; outside the frame: black)."""
    import cv2

    if maps is None:
        return image
    return cv2.remap(image, maps[0], maps[1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)


def distort_points(cam: RigCamera, uv: np.ndarray) -> np.ndarray:
    """Pinhole pixel coordinates (N, 2) (this module's convention) -> where the lens puts them."""
    x = (np.asarray(uv, np.float64) - cam.K[:2, 2]) / np.diag(cam.K)[:2]
    k1, k2, p1, p2, k3 = cam.coefficients
    r2 = np.sum(x * x, 1)
    radial = 1 + k1 * r2 + k2 * r2 ** 2 + k3 * r2 ** 3
    xd = x[:, 0] * radial + 2 * p1 * x[:, 0] * x[:, 1] + p2 * (r2 + 2 * x[:, 0] ** 2)
    yd = x[:, 1] * radial + p1 * (r2 + 2 * x[:, 1] ** 2) + 2 * p2 * x[:, 0] * x[:, 1]
    return np.stack([xd, yd], 1) * np.diag(cam.K)[:2] + cam.K[:2, 2]
