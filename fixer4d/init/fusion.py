"""Depth fusion (Eq. 1-2): per-view depth maps -> one coloured point cloud of a timestamp.

Eq. 1: every valid pixel (u, v) of view i is lifted to x = T_w<-c [D K^-1 (u+0.5, v+0.5, 1)^T; 1]
(``Camera.backproject_depth``), coloured by its pixel. Eq. 2: x is kept only when at least k
other views agree: projected into view j it lands inside the image, in front of the camera, on
a pixel whose depth D_j is valid and within a relative tolerance of x's depth in view j. The
union is then voxel down-sampled (voxel relative to the scene scale) and cleaned by statistical
outlier removal (open3d's definitions, ``filter_cloud``).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from fixer4d.errors import InputError
from fixer4d.geometry.camera import Camera
import fixer4d.init.constants as C


# Largest |coordinate| filter_cloud accepts: its output is float32 (max 3.4e38), and voxel
# means and neighbour distances of larger coordinates overflow on the way.
POINT_LIMIT = 1e30


@dataclass
class FusionConfig:
    """min_views: other views that must agree (k; 0 keeps every valid pixel). depth_tol: relative
    depth agreement. voxel_rel: voxel size / median depth of the fused points (0 disables).
    outlier_neighbors / outlier_std: statistical outlier removal (neighbors 0 disables)."""

    min_views: int = C.FUSION_MIN_VIEWS
    depth_tol: float = C.FUSION_DEPTH_TOL
    voxel_rel: float = C.FUSION_VOXEL_REL
    outlier_neighbors: int = C.FUSION_OUTLIER_NEIGHBORS
    outlier_std: float = C.FUSION_OUTLIER_STD

    def __post_init__(self) -> None:
        _check_count(self.min_views, "min_views")
        _check_positive(self.depth_tol, "depth_tol")
        _check_positive(self.voxel_rel, "voxel_rel", zero_ok=True)
        _check_count(self.outlier_neighbors, "outlier_neighbors")
        _check_positive(self.outlier_std, "outlier_std")


def _check_count(value, name: str) -> None:
    """InputError unless ``value`` is a whole number >= 0."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 0:
        raise InputError(f"fusion: {name} must be a whole number >= 0, got {value!r}")


def _check_positive(value, name: str, zero_ok: bool = False) -> None:
    """InputError unless ``value`` is a finite number > 0 (>= 0 with ``zero_ok``)."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        v = float("nan")
    if not (np.isfinite(v) and (v >= 0.0 if zero_ok else v > 0.0)) or isinstance(value, bool):
        raise InputError(f"fusion: {name} must be a finite number {'>= 0' if zero_ok else '> 0'}, got {value!r}")


def _check_image(image, i: int) -> None:
    """InputError for an image that is not float RGB (8-bit images would be clipped to white)."""
    img = np.asarray(image)
    if img.dtype.kind != "f":
        raise InputError(f"fusion: image {i} has dtype {img.dtype}; pass float RGB in [0, 1] (divide 8-bit by 255)")


def _clean_depth(depth: np.ndarray, valid: np.ndarray | None) -> np.ndarray:
    """Depth with every unusable pixel (zero, negative, NaN, inf, masked out) set to 0."""
    d = np.asarray(depth, np.float64)
    ok = np.isfinite(d) & (d > 0)
    if valid is not None:
        ok &= np.asarray(valid, bool)
    return np.where(ok, d, 0.0)


def consistent_points(images: Sequence[np.ndarray], depths: Sequence[np.ndarray], cameras: Sequence[Camera],
                      valids: Sequence[np.ndarray] | None = None, *, min_views: int = C.FUSION_MIN_VIEWS,
                      depth_tol: float = C.FUSION_DEPTH_TOL) -> tuple[np.ndarray, np.ndarray]:
    """Eq. 1-2 without the final filtering.

    images: V (H_i, W_i, 3) float RGB in [0, 1]; depths: V (H_i, W_i) z-depths (0/NaN/inf =
    none); cameras: V cameras of those sizes; valids: optional V (H_i, W_i) bool masks.
    Returns (points (N, 3) float64, colors (N, 3) float32); N may be 0, never NaN.
    """
    _check_count(min_views, "min_views")
    _check_positive(depth_tol, "depth_tol")
    V = len(cameras)
    if len(images) != V or len(depths) != V or (valids is not None and len(valids) != V):
        raise InputError(f"fusion: {len(images)} images, {len(depths)} depth maps"
                         f"{'' if valids is None else f', {len(valids)} masks'} for {V} cameras; pass one of each per view")
    if V == 0:
        return np.zeros((0, 3)), np.zeros((0, 3), np.float32)
    if min_views > V - 1:
        raise InputError(f"fusion: each point needs {min_views} other agreeing views but only {V} view(s) were given; "
                         f"pass more views or lower min_views")
    for i, cam in enumerate(cameras):
        if not isinstance(cam, Camera):
            raise InputError(f"fusion: camera {i} is a {type(cam).__name__}, not a fixer4d Camera")
        _check_image(images[i], i)
        size = (cam.height, cam.width)
        if np.asarray(depths[i]).shape != size:
            raise InputError(f"fusion: depth map {i} is {np.asarray(depths[i]).shape}, camera {cam.name!r} is {size}")
        if np.asarray(images[i]).shape[:2] != size:
            raise InputError(f"fusion: image {i} is {np.asarray(images[i]).shape[:2]}, camera {cam.name!r} is {size}; "
                             f"resize the image to the depth resolution")
        if valids is not None and np.asarray(valids[i]).shape != size:
            raise InputError(f"fusion: mask {i} is {np.asarray(valids[i]).shape}, camera {cam.name!r} is {size}")
    clean = [_clean_depth(depths[i], None if valids is None else valids[i]) for i in range(V)]
    pts_all, col_all = [], []
    for i, cam in enumerate(cameras):
        sel = clean[i] > 0
        if not sel.any():
            continue
        X = cam.backproject_depth(clean[i])[sel]  # Eq. 1
        colors = np.clip(np.nan_to_num(np.asarray(images[i], np.float32)[sel]), 0.0, 1.0)
        agree = np.zeros(X.shape[0], np.int32)
        for j, other in enumerate(cameras):
            if j == i:
                continue
            uv, z = other.project(X)
            with np.errstate(invalid="ignore"):
                iu = np.floor(uv[:, 0])
                iv = np.floor(uv[:, 1])
                inside = (z > 0) & (iu >= 0) & (iu < other.width) & (iv >= 0) & (iv < other.height)
            d_j = np.zeros(X.shape[0])
            d_j[inside] = clean[j][iv[inside].astype(np.int64), iu[inside].astype(np.int64)]
            with np.errstate(divide="ignore", invalid="ignore"):
                ok = inside & (d_j > 0) & (np.abs(z - d_j) <= depth_tol * d_j)  # Eq. 2
            agree += ok
        keep = agree >= min_views
        pts_all.append(X[keep])
        col_all.append(colors[keep])
    if not pts_all:
        return np.zeros((0, 3)), np.zeros((0, 3), np.float32)
    points = np.concatenate(pts_all)
    colors = np.concatenate(col_all).astype(np.float32)
    finite = np.all(np.isfinite(points), 1)
    return points[finite], colors[finite]


def filter_cloud(points: np.ndarray, colors: np.ndarray, cameras: Sequence[Camera], *,
                 voxel_rel: float = C.FUSION_VOXEL_REL, outlier_neighbors: int = C.FUSION_OUTLIER_NEIGHBORS,
                 outlier_std: float = C.FUSION_OUTLIER_STD) -> tuple[np.ndarray, np.ndarray]:
    """Voxel down-sampling (voxel = voxel_rel x median camera depth of the points) and
    statistical outlier removal, as open3d's ``voxel_down_sample`` and
    ``remove_statistical_outlier`` define them (numpy + scipy: importing open3d alone took 0.5 s
    of a 3 s init). Returns (points (M, 3) float32, colors (M, 3) float32)."""
    _check_positive(voxel_rel, "voxel_rel", zero_ok=True)
    _check_count(outlier_neighbors, "outlier_neighbors")
    _check_positive(outlier_std, "outlier_std")
    points = np.asarray(points, np.float64).reshape(-1, 3)
    colors = np.asarray(colors, np.float64).reshape(-1, 3)
    if points.shape[0] != colors.shape[0]:
        raise InputError(f"fusion: {points.shape[0]} points but {colors.shape[0]} colours; pass one colour per point")
    if not (np.all(np.isfinite(points)) and np.all(np.isfinite(colors))):
        raise InputError("fusion: non-finite points or colours; filter the cloud first")
    if points.size and float(np.max(np.abs(points))) > POINT_LIMIT:
        raise InputError(f"fusion: points reach {float(np.max(np.abs(points))):.3g}, beyond the float32 cloud's "
                         f"range (|coordinate| <= {POINT_LIMIT:g}); rescale the scene")
    if points.shape[0] == 0:
        return np.zeros((0, 3), np.float32), np.zeros((0, 3), np.float32)
    if voxel_rel > 0:
        points, colors = voxel_down_sample(points, colors, voxel_rel * scene_scale(points, cameras))
    if outlier_neighbors > 0 and len(points) > outlier_neighbors:
        keep = statistical_inliers(points, outlier_neighbors, outlier_std)
        points, colors = points[keep], colors[keep]
    return points.astype(np.float32), colors.astype(np.float32)


def voxel_down_sample(points: np.ndarray, colors: np.ndarray, voxel: float) -> tuple[np.ndarray, np.ndarray]:
    """One point per occupied voxel: the mean position and colour of its points. The grid starts
    half a voxel below the points' minimum (open3d's convention); voxels in lexicographic order
    of their (x, y, z) index."""
    ijk = np.floor((points - (points.min(0) - 0.5 * voxel)) / voxel).astype(np.int64)
    dims = ijk.max(0) + 1
    key = (ijk[:, 0] * dims[1] + ijk[:, 1]) * dims[2] + ijk[:, 2]
    _, inv, count = np.unique(key, return_inverse=True, return_counts=True)
    n = count.size
    mean = lambda x: np.stack([np.bincount(inv, weights=x[:, c], minlength=n) for c in range(3)], 1) / count[:, None]
    return mean(points), mean(colors)


def statistical_inliers(points: np.ndarray, neighbors: int, std_ratio: float) -> np.ndarray:
    """(N,) bool: a point's mean distance to its ``neighbors`` nearest points (itself included,
    as open3d counts it) is positive and below the cloud's mean of that distance + std_ratio x
    its standard deviation (Bessel-corrected)."""
    from scipy.spatial import cKDTree

    dist, _ = cKDTree(points).query(points, k=neighbors, workers=-1)
    avg = dist.reshape(len(points), -1).mean(1)  # k = 1 returns (N,)
    ok = avg > 0
    if ok.sum() < 2:
        return ok
    threshold = avg[ok].mean() + std_ratio * avg[ok].std(ddof=1)
    return ok & (avg < threshold)


def scene_scale(points: np.ndarray, cameras: Sequence[Camera]) -> float:
    """Median distance from the cameras' centres to the points: the viewing distance that voxel
    sizes are relative to."""
    centers = np.stack([c.center for c in cameras])
    sample = points[:: max(1, points.shape[0] // 20000)]
    d = np.linalg.norm(sample[:, None, :] - centers[None], axis=2).min(1)
    return float(max(np.median(d), 1e-9))


def fuse_depths(images: Sequence[np.ndarray], depths: Sequence[np.ndarray], cameras: Sequence[Camera],
                valids: Sequence[np.ndarray] | None = None, config: FusionConfig | None = None
                ) -> tuple[np.ndarray, np.ndarray]:
    """Eq. 1-2 then voxel down-sampling and outlier removal -> (points (N,3) float32, colors
    (N,3) float32 in [0,1]). See ``consistent_points`` for the inputs."""
    config = config or FusionConfig()
    pts, cols = consistent_points(images, depths, cameras, valids, min_views=config.min_views,
                                  depth_tol=config.depth_tol)
    return filter_cloud(pts, cols, cameras, voxel_rel=config.voxel_rel, outlier_neighbors=config.outlier_neighbors,
                        outlier_std=config.outlier_std)


def fuse_results(images: Sequence[np.ndarray], results, config: FusionConfig | None = None
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Fuse DepthResults (from any DepthEstimator): the images are resized to each result's
    working resolution first."""
    import cv2

    if len(images) != len(results):
        raise InputError(f"fusion: {len(images)} images for {len(results)} depth results; pass one image per view")
    imgs = []
    for i, (img, res) in enumerate(zip(images, results)):
        _check_image(img, i)
        img = np.asarray(img, np.float32)
        if img.shape[:2] != res.depth.shape:
            img = cv2.resize(img, (res.depth.shape[1], res.depth.shape[0]), interpolation=cv2.INTER_AREA)
        imgs.append(img)
    return fuse_depths(imgs, [r.depth for r in results], [r.camera for r in results], [r.valid for r in results], config)
