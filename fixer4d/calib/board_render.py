"""A synthetic board capture: a ChArUco board moved through the common view of known cameras.

Each view is exact: the board image is warped into the camera with the homography its plane
induces (K [r1 r2 t], board metres -> pixels), rendered ``SUPERSAMPLE`` times larger and
area-averaged down, over a cluttered background; then mild blur and noise are added. The cameras
are the ground truth of ``fixer4d.calib.board_calib`` (tests, benchmarks/calibration_board.py).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from fixer4d.calib.board import BOARD_JSON, BoardSpec, board_image
from fixer4d.geometry.camera import Camera

# Each output pixel averages SUPERSAMPLE^2 warped samples: the board's edges are anti-aliased
# like a real sensor's pixel area, so corners do not snap to the pixel grid.
SUPERSAMPLE = 4
# Board texture resolution: below the smallest square a camera sees after supersampling (about
# 15 px x 4 at 320x240), so the warp only magnifies it: bilinear minification aliases the edges
# (measured: corner errors 0.08 px at 48, 0.12 px at 96 with 2x supersampling).
TEXTURE_PIXELS_PER_SQUARE = 48
# Defaults of a "mild" capture: a Gaussian blur of 0.5 px (a focused lens) and noise of
# 2 / 255 (a well-lit sensor).
BLUR_PX = 0.5
NOISE = 2.0 / 255.0
# Margin (share of the larger image side) of the pinhole render a lens view is resampled from:
# barrel distortion shows rays beyond the pinhole image's edge.
LENS_MARGIN = 0.25


def board_poses(spec: BoardSpec, cameras: list[Camera], target: np.ndarray, spread: np.ndarray | float,
                count: int = 30, tilt_deg: float = 40.0, seed: int = 0) -> list[np.ndarray]:
    """``count`` board-to-world poses (4, 4) (board metres -> world): the board's centre uniform in
    the box ``target`` +- ``spread`` (world units), its printed face towards the cameras' mean
    centre, tilted uniformly within +-``tilt_deg`` about both board axes and rolled +-45 degrees."""
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(seed)
    mean_centre = np.mean([c.center for c in cameras], 0)
    right = cameras[0].R[:, 0]
    middle = np.array([spec.squares_x, spec.squares_y, 0.0]) * spec.square_m / 2
    poses = []
    for _ in range(count):
        p = np.asarray(target, np.float64) + rng.uniform(-1, 1, 3) * spread
        z = p - mean_centre  # the printed face is seen from the board's -z side
        z /= np.linalg.norm(z)
        x = right - z * (right @ z)
        x /= np.linalg.norm(x)
        facing = np.stack([x, np.cross(z, x), z], 1)
        tilt = Rotation.from_euler("xyz", [*rng.uniform(-tilt_deg, tilt_deg, 2), rng.uniform(-45, 45)],
                                   degrees=True).as_matrix()
        T = np.eye(4)
        T[:3, :3] = facing @ tilt
        T[:3, 3] = p - T[:3, :3] @ middle
        poses.append(T)
    return poses


def plane_homography(spec: BoardSpec, camera: Camera, board_to_world: np.ndarray, margin_px: int,
                     pixels_per_square: int) -> np.ndarray:
    """(3, 3) homography from ``board_image`` pixels to the camera's pixels, both in OpenCV's
    convention (pixel centres at integers), as cv2.warpPerspective takes it."""
    b2c = camera.w2c @ board_to_world
    K_metric = camera.K @ b2c[:3][:, [0, 1, 3]]  # board (x, y, 1) metres -> fixer4d pixels
    to_opencv = np.array([[1.0, 0.0, -0.5], [0.0, 1.0, -0.5], [0.0, 0.0, 1.0]])
    s = pixels_per_square / spec.square_m
    texture = np.array([[s, 0.0, margin_px - 0.5], [0.0, s, margin_px - 0.5], [0.0, 0.0, 1.0]])
    return to_opencv @ K_metric @ np.linalg.inv(texture)


def _background(camera: Camera, rng: np.random.Generator) -> np.ndarray:
    """(H, W) float32 clutter: smooth random grey blotches."""
    import cv2

    coarse = rng.uniform(0.25, 0.75, (max(2, camera.height // 12), max(2, camera.width // 12))).astype(np.float32)
    return cv2.resize(coarse, (camera.width, camera.height), interpolation=cv2.INTER_CUBIC)


def render_board_view(spec: BoardSpec, camera: Camera, board_to_world: np.ndarray | None, background: np.ndarray,
                      texture: tuple[np.ndarray, int, int]) -> np.ndarray:
    """(H, W) float32 grey in [0, 1]: ``background`` (H, W) with the board at ``board_to_world``
    drawn over it (None, or the board's back facing the camera: the background alone).
    ``texture`` is (board image, margin px, pixels per square)."""
    import cv2

    if board_to_world is None or (camera.center - board_to_world[:3, 3]) @ board_to_world[:3, 2] > 0:
        return background.copy()
    image, margin, pps = texture
    big = camera.scaled(SUPERSAMPLE)
    H = plane_homography(spec, big, board_to_world, margin, pps)
    size = (big.width, big.height)
    board = cv2.warpPerspective(image.astype(np.float32) / 255.0, H, size, flags=cv2.INTER_LINEAR,
                                borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    cover = cv2.warpPerspective(np.ones(image.shape, np.float32), H, size, flags=cv2.INTER_LINEAR,
                                borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    out = cv2.resize(background, size, interpolation=cv2.INTER_NEAREST)
    out += cover * (board - out)
    return cv2.resize(out, (camera.width, camera.height), interpolation=cv2.INTER_AREA)


def lens_view(camera: Camera, distortion: dict[str, float]) -> tuple[Camera, tuple[np.ndarray, np.ndarray]]:
    """A pinhole camera with a margin of ``LENS_MARGIN`` around ``camera``'s image (same focal
    and pose), and the cv2.remap maps that turn its renders into ``camera``'s image through the
    lens ``distortion`` (OpenCV's k1, k2, p1, p2, k3): each lens pixel samples the pinhole pixel
    its ray comes from (OpenCV's iterative undistortion, converged to 1e-10)."""
    import cv2

    from fixer4d.calib.rig import DISTORTION_KEYS, opencv_K

    pad = int(np.ceil(LENS_MARGIN * max(camera.width, camera.height)))
    K = camera.K.copy()
    K[:2, 2] += pad
    wide = Camera(K, camera.c2w, camera.width + 2 * pad, camera.height + 2 * pad, camera.name)
    u, v = np.meshgrid(np.arange(camera.width, dtype=np.float64), np.arange(camera.height, dtype=np.float64))
    Kc = opencv_K(camera.K)
    coefficients = np.array([distortion.get(k, 0.0) for k in DISTORTION_KEYS])
    criteria = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, 1e-10)
    pinhole = cv2.undistortPoints(np.stack([u, v], -1).reshape(-1, 1, 2), Kc, coefficients, R=None, P=Kc,
                                  criteria=criteria)
    maps = (pinhole.reshape(camera.height, camera.width, 2) + pad).astype(np.float32)
    return wide, (np.ascontiguousarray(maps[..., 0]), np.ascontiguousarray(maps[..., 1]))


def write_board_capture(spec: BoardSpec, cameras: list[Camera], poses: list[np.ndarray], root: str | Path, *,
                        blur_px: float = BLUR_PX, noise: float = NOISE, hidden: dict[str, set[int]] | None = None,
                        distortion: dict[str, dict[str, float]] | None = None, seed: int = 0) -> Path:
    """One image folder per camera (root/<camera name>/000000.png ...), frame f showing the board
    at ``poses[f]`` (except the frames ``hidden[name]`` lists: no board), seen through the lens
    ``distortion[name]`` when given (else a pinhole), and root/board.json."""
    import cv2

    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    margin = TEXTURE_PIXELS_PER_SQUARE // 2
    texture = (board_image(spec, TEXTURE_PIXELS_PER_SQUARE, margin), margin, TEXTURE_PIXELS_PER_SQUARE)
    rng = np.random.default_rng(seed)
    for cam in cameras:
        folder = root / cam.name
        folder.mkdir(exist_ok=True)
        lens = (distortion or {}).get(cam.name)
        view, maps = lens_view(cam, lens) if lens else (cam, None)
        background = _background(view, rng)
        for f, pose in enumerate(poses):
            img = render_board_view(spec, view, None if f in (hidden or {}).get(cam.name, ()) else pose, background,
                                    texture)
            if maps is not None:
                img = cv2.remap(img, maps[0], maps[1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
            if blur_px > 0:
                img = cv2.GaussianBlur(img, (0, 0), blur_px)
            img = np.clip(img + rng.normal(0.0, noise, img.shape), 0, 1)
            cv2.imwrite(str(folder / f"{f:06d}.png"), np.round(img * 255).astype(np.uint8))
    spec.write(root / BOARD_JSON)
    return root
