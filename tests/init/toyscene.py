"""A tiny ray-cast scene for the init tests: textured analytic geometry, exact depth.

Independent of fixer4d.scene (the scene engineer's generator): a back wall (plane z = -1), a
floor (plane y = 1, OpenCV-style y down) and a sphere that moves with t, all carrying a
multi-octave value-noise texture so that SIFT and ZNCC find structure. ``render`` returns the
image and the z-depth (inf where nothing is hit) of any Camera, with pixel centres at
(u + 0.5, v + 0.5).
"""
from __future__ import annotations

import numpy as np

from fixer4d.geometry.camera import Camera
from fixer4d.scene.base import MultiViewVideo, SceneBounds

_RNG = np.random.default_rng(1234)
_GRIDS = [_RNG.random((n, n, 3)).astype(np.float64) for n in (16, 32, 64, 128, 256)]


def noise_texture(s: np.ndarray, t: np.ndarray, period: float = 16.0) -> np.ndarray:
    """Periodic multi-octave value noise at surface coordinates (s, t) -> (..., 3) RGB in [0, 1]."""
    out = np.zeros(s.shape + (3,))
    total = 0.0
    for i, grid in enumerate(_GRIDS):
        n = grid.shape[0]
        x = (s / period) % 1.0 * n
        y = (t / period) % 1.0 * n
        x0 = np.floor(x).astype(int)
        y0 = np.floor(y).astype(int)
        fx = (x - x0)[..., None]
        fy = (y - y0)[..., None]
        x0 %= n
        y0 %= n
        x1 = (x0 + 1) % n
        y1 = (y0 + 1) % n
        v = (grid[y0, x0] * (1 - fx) * (1 - fy) + grid[y0, x1] * fx * (1 - fy)
             + grid[y1, x0] * (1 - fx) * fy + grid[y1, x1] * fx * fy)
        w = 0.8 ** (len(_GRIDS) - 1 - i)  # finer octaves weigh more: rich local texture
        out += w * v
        total += w
    return np.clip(out / total * 1.4 - 0.2, 0.0, 1.0)


def sphere_center(t: float) -> np.ndarray:
    return np.array([0.3 * np.sin(2 * np.pi * t), 0.0, 0.2])


SPHERE_RADIUS = 0.45


def render(camera: Camera, t: float, *, textured: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """(H, W, 3) float32 image and (H, W) float32 z-depth (inf where nothing is hit)."""
    d = camera.ray_directions().reshape(-1, 3)  # camera z = 1 per direction
    o = camera.center
    n = d.shape[0]
    best = np.full(n, np.inf)
    color = np.zeros((n, 3))
    # back wall z = -1, x,y in [-3, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        lam = (-1.0 - o[2]) / d[:, 2]
    p = o + lam[:, None] * d
    hit = (lam > 0) & (np.abs(p[:, 0]) < 3) & (np.abs(p[:, 1]) < 3)
    upd = hit & (lam < best)
    best[upd] = lam[upd]
    color[upd] = noise_texture(p[upd, 0], p[upd, 1])
    # floor y = 1, z in [-1, 3]
    with np.errstate(divide="ignore", invalid="ignore"):
        lam = (1.0 - o[1]) / d[:, 1]
    p = o + lam[:, None] * d
    hit = (lam > 0) & (np.abs(p[:, 0]) < 3) & (p[:, 2] > -1) & (p[:, 2] < 3)
    upd = hit & (lam < best)
    best[upd] = lam[upd]
    color[upd] = noise_texture(p[upd, 0] + 7.1, p[upd, 2] + 3.3)
    # sphere
    c = sphere_center(t)
    oc = o - c
    a = np.sum(d * d, 1)
    b = 2 * d @ oc
    cc = oc @ oc - SPHERE_RADIUS ** 2
    disc = b * b - 4 * a * cc
    ok = disc >= 0
    lam = np.full(n, np.inf)
    lam[ok] = (-b[ok] - np.sqrt(disc[ok])) / (2 * a[ok])
    upd = ok & (lam > 0) & (lam < best)
    best[upd] = lam[upd]
    p = o + lam[upd, None] * d[upd]
    q = (p - c) / SPHERE_RADIUS
    color[upd] = noise_texture(np.arctan2(q[:, 0], q[:, 2]) * 0.6, np.arccos(np.clip(q[:, 1], -1, 1)) * 0.6)
    if not textured:
        color[np.isfinite(best)] = 0.5
    # lambda is the z-depth because directions have camera z = 1
    depth = best.reshape(camera.height, camera.width).astype(np.float32)
    return color.reshape(camera.height, camera.width, 3).astype(np.float32), depth


def rig(width: int = 160, height: int = 120, n_train: int = 4, n_test: int = 1) -> list[Camera]:
    """Train cameras on an arc in front of the wall, looking at the sphere, then held-out ones."""
    cams = []
    angles = np.radians(np.linspace(-30, 30, n_train))
    for i, a in enumerate(angles):
        elev = 0.3 if i % 2 else -0.1
        eye = np.array([3.2 * np.sin(a), elev, 0.2 + 3.2 * np.cos(a)])
        cams.append(Camera.look_at(eye, [0, 0.2, 0], up=(0, -1, 0), fov_y=np.radians(55), width=width,
                                   height=height, name=f"train{i}"))
    for j in range(n_test):
        eye = np.array([0.4 * (j + 1), 0.1, 3.3])
        cams.append(Camera.look_at(eye, [0, 0.2, 0], up=(0, -1, 0), fov_y=np.radians(55), width=width,
                                   height=height, name=f"test{j}"))
    return cams


class ToyScene(MultiViewVideo):
    """A MultiViewVideo over ``render``: ground-truth depth, a render_gt for any camera."""

    def __init__(self, width: int = 160, height: int = 120, num_frames: int = 2, textured: bool = True) -> None:
        super().__init__()
        self.name = "toy"
        self.cameras = rig(width, height)
        self.train_ids = [0, 1, 2, 3]
        self.test_ids = [4]
        self.num_frames = num_frames
        self.textured = textured

    def render_gt(self, camera: Camera, t: float) -> tuple[np.ndarray, np.ndarray]:
        return render(camera, t, textured=self.textured)

    def _load_frame(self, frame: int, cam: int) -> np.ndarray:
        return render(self.cameras[cam], self.time(frame), textured=self.textured)[0]

    def _load_depth(self, frame: int, cam: int) -> np.ndarray:
        return render(self.cameras[cam], self.time(frame), textured=self.textured)[1]

    @property
    def has_depth(self) -> bool:
        return True

    def bounds(self) -> SceneBounds:
        return SceneBounds(near=1.5, far=8.0, bbox_min=np.array([-3.0, -3.0, -1.0]),
                           bbox_max=np.array([3.0, 1.0, 3.0]))
