"""The sparse baseline: per frame, SIFT + exhaustive matching + triangulation with fixed poses.

This is the COLMAP point cloud that STGS-style methods start from; each frame is triangulated
on its own with the rig's (given or SfM) poses, in a temporary COLMAP project that is removed
afterwards.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from fixer4d.geometry.camera import Camera
import fixer4d.init.constants as C
from fixer4d.init.cloud import FrameCloud
from fixer4d.init.poses import ColmapWorkspace


@dataclass
class SparseConfig:
    """max_features: SIFT features per image. num_threads: pycolmap threads (-1 = all cores: faster, not reproducible;
    see constants.COLMAP_THREADS)."""

    max_features: int = C.SIFT_MAX_FEATURES
    num_threads: int = C.COLMAP_THREADS


def sparse_cloud(images: list[np.ndarray], cameras: list[Camera], frame: int, time_value: float,
                 config: SparseConfig | None = None) -> tuple[FrameCloud, dict]:
    """Triangulate one timestamp's V views with fixed poses.

    images: V (H, W, 3) float32 RGB in [0, 1]; cameras: the V posed cameras. Returns the cloud
    (exact duplicate points merged) and stats: keypoints per view, verified pairs, inlier matches,
    points, seconds. A frame where nothing matches gives an empty cloud, not an error.
    """
    config = config or SparseConfig()
    t0 = time.perf_counter()
    with ColmapWorkspace(images, cameras, max_features=config.max_features, num_threads=config.num_threads) as ws:
        stats = ws.extract_and_match()
        if stats["verified_pairs"] > 0:
            points, colors = ws.triangulate()
        else:
            points, colors = np.zeros((0, 3), np.float32), np.zeros((0, 3), np.float32)
    # COLMAP can create two tracks at the same position when a feature matches in two ways.
    _, first = np.unique(points, axis=0, return_index=True)
    first.sort()
    cloud = FrameCloud(frame, time_value, points[first], colors[first])
    stats.update(points=len(cloud), seconds=time.perf_counter() - t0)
    return cloud, stats
