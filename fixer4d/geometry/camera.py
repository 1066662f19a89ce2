"""Pinhole cameras in OpenCV axes (x right, y down, z forward), float64 (docs/design.md §4).

Pixel convention: the pixel with integer index (u, v) covers [u, u+1) x [v, v+1) in the
K-projection, so its centre is at (u + 0.5, v + 0.5). Under this convention resizing an image
by a factor s scales fx, fy, cx, cy by exactly s (no half-pixel shift), and every component
(rasterizer, MVS, fusion, restorer warps, GL shader) uses it.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from fixer4d.errors import InputError

# OpenCV (x right, y down, z forward) <-> OpenGL (x right, y up, z backward): flip y and z.
CV_TO_GL = np.diag([1.0, -1.0, -1.0, 1.0])

# Skew K[0, 1] accepted as zero when |skew| <= SKEW_REL_TOL * fx: float round-off of a K
# computed elsewhere, at most ~1e-9 px of shift per pixel of height. Beyond it the rasterizers
# (which use fx, fy, cx, cy only) and ``project`` (which uses K) would place points differently.
SKEW_REL_TOL = 1e-9
# A rotation block is accepted when max|R^T R - I| and |det R - 1| are below this: poses stored
# in float32 or decomposed from a projection matrix are orthonormal to ~1e-6; a mirror (det -1)
# or a scaled rotation is off by O(1).
ROTATION_TOL = 1e-4
# The c2w bottom row must be [0, 0, 0, 1] to within this (absolute): anything else is a
# projective matrix, not a rigid pose.
BOTTOM_ROW_TOL = 1e-9


def _image_side(value: Any, name: str, what: str) -> int:
    """A positive whole number of pixels (int, or a float/array scalar with an integral value)."""
    try:
        side = int(value)
        whole = float(value) == side
    except (TypeError, ValueError, OverflowError):
        side, whole = 0, False
    if not whole or side <= 0:
        raise InputError(f"camera {name!r}: image size: {what} must be a positive whole number of pixels, got {value!r}")
    return side


def _check_intrinsics(K: np.ndarray, name: str) -> np.ndarray:
    """The validated (3, 3) pinhole K: upper-triangular, positive focal lengths, zero skew,
    K[2, 2] = 1 (a positive K[2, 2] != 1 is divided out with a warning: K and K / K[2, 2]
    project alike). Raises InputError naming the camera and the offending entry."""
    if K[1, 0] != 0.0 or K[2, 0] != 0.0 or K[2, 1] != 0.0:
        raise InputError(f"camera {name!r}: K must be upper-triangular [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]; "
                         f"got lower entries K[1,0]={K[1, 0]}, K[2,0]={K[2, 0]}, K[2,1]={K[2, 1]}")
    if not K[2, 2] > 0.0:
        raise InputError(f"camera {name!r}: K[2,2] must be 1 (or positive, to be normalised), got {K[2, 2]}")
    if K[2, 2] != 1.0:
        warnings.warn(f"camera {name!r}: K[2,2] = {K[2, 2]}; dividing K by it (the same projection)",
                      UserWarning, stacklevel=4)
        K = K / K[2, 2]
        if not np.all(np.isfinite(K)):
            raise InputError(f"camera {name!r}: K / K[2,2] overflows; pass K with K[2,2] = 1")
    if K[0, 0] <= 0 or K[1, 1] <= 0:
        raise InputError(f"camera {name!r}: focal lengths must be positive, got fx={K[0, 0]}, fy={K[1, 1]}")
    if abs(K[0, 1]) > SKEW_REL_TOL * K[0, 0]:
        raise InputError(f"camera {name!r}: skew K[0,1] = {K[0, 1]} is not supported (the rasterizers use fx, fy, "
                         "cx, cy only); undistort/resample the images to a zero-skew K")
    return K


def _check_pose(c2w: np.ndarray, name: str) -> None:
    """Raise InputError unless c2w is a rigid camera-to-world: a proper rotation (within
    ROTATION_TOL, det +1, no mirror or scale) and the bottom row [0, 0, 0, 1]."""
    if np.max(np.abs(c2w[3] - np.array([0.0, 0.0, 0.0, 1.0]))) > BOTTOM_ROW_TOL:
        raise InputError(f"camera {name!r}: the c2w bottom row must be [0, 0, 0, 1], got {c2w[3].tolist()}; "
                         "pass a rigid camera-to-world matrix")
    R = c2w[:3, :3]
    ortho = float(np.max(np.abs(R.T @ R - np.eye(3))))
    det = float(np.linalg.det(R))
    if not (ortho <= ROTATION_TOL and abs(det - 1.0) <= ROTATION_TOL):
        what = "a mirror (det -1)" if det < 0 else f"not orthonormal (max|R^T R - I| = {ortho:.3g}, det {det:.6g})"
        raise InputError(f"camera {name!r}: the c2w rotation is {what}; pass a proper rotation (orthonormal, det +1)")


@dataclass(frozen=True, eq=False)
class Camera:
    """A calibrated pinhole camera.

    K: (3, 3) intrinsics in pixels, [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0 (no
    skew; a positive K[2, 2] != 1 is divided out with a warning). c2w: (4, 4) (or (3, 4))
    camera-to-world, OpenCV axes: a proper rotation (det +1, orthonormal to ROTATION_TOL) and the
    bottom row [0, 0, 0, 1]. width, height: image size in pixels. name: an identifier (e.g.
    "cam00", "30"). Anything else raises InputError here, where the camera is built.
    """

    K: np.ndarray
    c2w: np.ndarray
    width: int
    height: int
    name: str = ""
    _w2c: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        try:
            K = np.array(self.K, dtype=np.float64)
            c2w = np.array(self.c2w, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise InputError(f"camera {self.name!r}: K and c2w must be numeric matrices ({exc})") from None
        if K.size != 9:
            raise InputError(f"camera {self.name!r}: K must be 3x3, got shape {K.shape}")
        K = K.reshape(3, 3)
        if c2w.shape == (3, 4):
            c2w = np.vstack([c2w, [0.0, 0.0, 0.0, 1.0]])
        if c2w.shape != (4, 4):
            raise InputError(f"camera {self.name!r}: c2w must be 3x4 or 4x4, got shape {c2w.shape}")
        if not (np.all(np.isfinite(K)) and np.all(np.isfinite(c2w))):
            raise InputError(f"camera {self.name!r}: non-finite values in K or c2w; fix the pose/intrinsics source")
        width, height = _image_side(self.width, self.name, "width"), _image_side(self.height, self.name, "height")
        K = _check_intrinsics(K, self.name)
        _check_pose(c2w, self.name)
        K.setflags(write=False)
        c2w.setflags(write=False)
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "c2w", c2w)
        object.__setattr__(self, "width", width)
        object.__setattr__(self, "height", height)
        w2c = np.linalg.inv(c2w)
        if not np.all(np.isfinite(w2c)):
            raise InputError(f"camera {self.name!r}: the pose's translation {c2w[:3, 3].tolist()} is too large to "
                             "invert in float64; rescale the scene")
        w2c.setflags(write=False)
        object.__setattr__(self, "_w2c", w2c)

    # ---- basic properties -------------------------------------------------------------
    @property
    def w2c(self) -> np.ndarray:
        """(4, 4) world-to-camera."""
        return self._w2c

    @property
    def R(self) -> np.ndarray:
        """(3, 3) camera-to-world rotation (columns are the camera axes in world)."""
        return self.c2w[:3, :3]

    @property
    def center(self) -> np.ndarray:
        """(3,) camera centre in world coordinates."""
        return self.c2w[:3, 3].copy()

    @property
    def forward(self) -> np.ndarray:
        """(3,) unit viewing direction (+z of the camera) in world."""
        return self.c2w[:3, 2] / np.linalg.norm(self.c2w[:3, 2])

    @property
    def fx(self) -> float:
        return float(self.K[0, 0])

    @property
    def fy(self) -> float:
        return float(self.K[1, 1])

    @property
    def cx(self) -> float:
        return float(self.K[0, 2])

    @property
    def cy(self) -> float:
        return float(self.K[1, 2])

    @property
    def fov_y(self) -> float:
        """Vertical field of view in radians."""
        return 2.0 * float(np.arctan(self.height / (2.0 * self.fy)))

    @property
    def fov_x(self) -> float:
        return 2.0 * float(np.arctan(self.width / (2.0 * self.fx)))

    # ---- projection -------------------------------------------------------------------
    def world_to_camera(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) world points -> (N, 3) camera-frame points."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        return p @ self.w2c[:3, :3].T + self.w2c[:3, 3]

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Project world points (N, 3) to continuous pixel coordinates.

        Returns (uv (N, 2), depth (N,)): depth is the camera-frame z; uv = (K X / z)[:2], so a
        point on the centre of pixel (i, j) has uv = (i + 0.5, j + 0.5). Points with z <= 0 get
        uv = NaN (they have no image).
        """
        pc = self.world_to_camera(points)
        z = pc[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            uvw = pc @ self.K.T
            uv = uvw[:, :2] / uvw[:, 2:3]
        uv[z <= 0] = np.nan
        return uv, z

    def backproject(self, uv: np.ndarray, depth: np.ndarray) -> np.ndarray:
        """Continuous pixel coordinates (N, 2) at camera-frame depth z (N,) -> world points (N, 3).

        To back-project pixel (i, j) pass uv = (i + 0.5, j + 0.5) (see ``pixel_centers``).
        """
        uv = np.asarray(uv, dtype=np.float64).reshape(-1, 2)
        z = np.asarray(depth, dtype=np.float64).reshape(-1)
        rays = np.concatenate([uv, np.ones((uv.shape[0], 1))], 1) @ np.linalg.inv(self.K).T
        pc = rays * z[:, None]
        return pc @ self.R.T + self.c2w[:3, 3]

    def pixel_centers(self) -> np.ndarray:
        """(H, W, 2) continuous coordinates (u + 0.5, v + 0.5) of every pixel centre."""
        u = np.arange(self.width, dtype=np.float64) + 0.5
        v = np.arange(self.height, dtype=np.float64) + 0.5
        uu, vv = np.meshgrid(u, v)
        return np.stack([uu, vv], -1)

    def ray_directions(self, normalize: bool = False) -> np.ndarray:
        """(H, W, 3) world-space directions through every pixel centre.

        With ``normalize=False`` each direction has camera-frame z = 1, so a depth map (z-depth)
        multiplies it directly: X = center + depth * dir.
        """
        uv = self.pixel_centers().reshape(-1, 2)
        rays = np.concatenate([uv, np.ones((uv.shape[0], 1))], 1) @ np.linalg.inv(self.K).T
        d = rays @ self.R.T
        if normalize:
            d = d / np.linalg.norm(d, axis=1, keepdims=True)
        return d.reshape(self.height, self.width, 3)

    def backproject_depth(self, depth: np.ndarray) -> np.ndarray:
        """A (H, W) z-depth map -> (H, W, 3) world points through pixel centres (Eq. 1)."""
        depth = np.asarray(depth, dtype=np.float64)
        if depth.shape != (self.height, self.width):
            raise InputError(f"camera {self.name!r}: depth shape {depth.shape} != image {self.height}x{self.width}")
        return self.center[None, None, :] + depth[..., None] * self.ray_directions()

    # ---- derived cameras --------------------------------------------------------------
    def resized(self, width: int, height: int) -> "Camera":
        """The same camera for an image resized to (width, height): K rows scale with the image."""
        sx = width / self.width
        sy = height / self.height
        K = self.K.copy()
        K[0, :] *= sx
        K[1, :] *= sy
        return Camera(K, self.c2w, width, height, self.name)

    def scaled(self, factor: float) -> "Camera":
        """Resize by a factor (e.g. 0.5 for half resolution), rounding the size to whole pixels."""
        if not np.isfinite(self.width * factor) or not np.isfinite(self.height * factor) or not factor > 0:
            raise InputError(f"camera {self.name!r}: scale factor must be > 0 with a finite image size, got {factor}")
        return self.resized(max(1, int(round(self.width * factor))), max(1, int(round(self.height * factor))))

    def with_pose(self, c2w: np.ndarray, name: str | None = None) -> "Camera":
        return Camera(self.K, c2w, self.width, self.height, self.name if name is None else name)

    # ---- OpenGL boundary --------------------------------------------------------------
    def c2w_opengl(self) -> np.ndarray:
        """(4, 4) camera-to-world with OpenGL camera axes (x right, y up, z backward)."""
        return self.c2w @ CV_TO_GL

    @staticmethod
    def c2w_from_opengl(c2w_gl: np.ndarray) -> np.ndarray:
        """Inverse of ``c2w_opengl``: OpenGL-axes c2w -> OpenCV-axes c2w."""
        return np.asarray(c2w_gl, dtype=np.float64) @ CV_TO_GL

    def projection_opengl(self, near: float, far: float) -> np.ndarray:
        """(4, 4) OpenGL clip-space projection matching K exactly, including the principal point.

        Built so that a point projecting to continuous pixel (u, v) under K lands at NDC
        x = 2u/W - 1, y = 1 - 2v/H; the pixel-centre convention is preserved.
        """
        W, H = self.width, self.height
        P = np.zeros((4, 4))
        P[0, 0] = 2.0 * self.fx / W
        P[0, 2] = 1.0 - 2.0 * self.cx / W
        P[1, 1] = 2.0 * self.fy / H
        P[1, 2] = 2.0 * self.cy / H - 1.0
        P[2, 2] = -(far + near) / (far - near)
        P[2, 3] = -2.0 * far * near / (far - near)
        P[3, 2] = -1.0
        return P

    # ---- constructors and serialization -----------------------------------------------
    @staticmethod
    def intrinsics_from_fov(fov_y: float, width: int, height: int) -> np.ndarray:
        """Square-pixel K with a centred principal point for a vertical fov in radians."""
        fy = height / (2.0 * np.tan(fov_y / 2.0))
        return np.array([[fy, 0.0, width / 2.0], [0.0, fy, height / 2.0], [0.0, 0.0, 1.0]])

    @classmethod
    def look_at(cls, eye, target, up=(0.0, 1.0, 0.0), *, K=None, fov_y: float = np.radians(50.0),
                width: int = 320, height: int = 240, name: str = "") -> "Camera":
        """A camera at ``eye`` looking at ``target``. ``up`` is the world direction that should
        appear upward in the image (OpenCV's image-up is camera -y)."""
        eye = np.asarray(eye, np.float64)
        z = np.asarray(target, np.float64) - eye
        nz = np.linalg.norm(z)
        if nz < 1e-12:
            raise InputError("look_at: eye and target coincide; no viewing direction")
        z /= nz
        x = np.cross(z, np.asarray(up, np.float64))
        nx = np.linalg.norm(x)
        if nx < 1e-9:
            raise InputError("look_at: up is parallel to the viewing direction; choose another up vector")
        x /= nx
        y = np.cross(z, x)
        c2w = np.eye(4)
        c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = x, y, z, eye
        if K is None:
            K = cls.intrinsics_from_fov(fov_y, width, height)
        return cls(K, c2w, width, height, name)

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "width": self.width, "height": self.height,
                "K": self.K.tolist(), "c2w": self.c2w.tolist()}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "Camera":
        return cls(np.array(d["K"]), np.array(d["c2w"]), int(d["width"]), int(d["height"]), str(d.get("name", "")))

    def __repr__(self) -> str:
        c = self.center
        return (f"Camera({self.name!r}, {self.width}x{self.height}, f=({self.fx:.1f},{self.fy:.1f}), "
                f"center=({c[0]:.3f},{c[1]:.3f},{c[2]:.3f}))")


def rig_extent(cameras: list[Camera]) -> float:
    """Radius of the camera rig: the largest distance of a centre from the centres' mean
    (the 3DGS 'cameras_extent' that scales position learning rates), at least 1e-6."""
    centers = np.stack([c.center for c in cameras])
    return max(float(np.max(np.linalg.norm(centers - centers.mean(0), axis=1))), 1e-6)
