"""The plane sweep's per-view depth ranges (near, far z-depths) from the capture's own cues:
sparse SfM points, the cameras' common view, or the axis-convergence default."""
from __future__ import annotations

from typing import Sequence

import numpy as np

from fixer4d.errors import InputError
from fixer4d.geometry.camera import Camera, rig_extent
from fixer4d.geometry.rig import axes_converge, axes_system, common_view_bounds
import fixer4d.init.constants as C


def depth_ranges_from_points(points: np.ndarray, cameras: Sequence[Camera]) -> list[tuple[float, float]] | None:
    """Per-view (near, far) from 3D points (e.g. SfM) seen in the view: percentiles of their
    depths widened by a margin. None when a view sees fewer than 10 points."""
    points = np.asarray(points, np.float64).reshape(-1, 3)
    out = []
    for cam in cameras:
        uv, z = cam.project(points)
        ok = (z > 0) & np.all(np.isfinite(uv), 1)
        ok &= (uv[:, 0] >= 0) & (uv[:, 0] < cam.width) & (uv[:, 1] >= 0) & (uv[:, 1] < cam.height)
        if ok.sum() < 10:
            return None
        lo, hi = np.percentile(z[ok], C.MVS_POINTS_PERCENTILES)
        out.append((float(lo / C.MVS_POINTS_MARGIN), float(hi * C.MVS_POINTS_MARGIN)))
    return out


def depth_ranges_from_rig(cameras: Sequence[Camera]) -> list[tuple[float, float]] | None:
    """Per-view (near, far): the z-range of the cameras' common view (frustum overlap) in each
    view; None when the frusta share no view."""
    try:
        vb = common_view_bounds(cameras)
    except InputError:
        return None
    return [(float(a), float(b)) for a, b in vb.depth_ranges]


def scene_depth_ranges(cameras: Sequence[Camera], sfm_points: np.ndarray | None = None
                       ) -> tuple[list[tuple[float, float]], str]:
    """The plane sweep's per-view depth ranges from the capture's own cues, and their source:
    sparse SfM points when given (and seen by every view), else the common view of the (train)
    ``cameras``, else the axis-convergence default. Never ground truth: synthetic scenes get
    exactly what a real capture would."""
    if sfm_points is not None:
        ranges = depth_ranges_from_points(sfm_points, cameras)
        if ranges is not None:
            return ranges, "sfm points"
    ranges = depth_ranges_from_rig(cameras)
    if ranges is not None:
        return ranges, "common view of the train cameras"
    return default_depth_ranges(cameras), "axis convergence default"


def default_depth_ranges(cameras: Sequence[Camera]) -> list[tuple[float, float]]:
    """Without points or a common view: the least-squares point closest to all optical axes is
    where a converging rig looks; the range spans a factor around its distance. For parallel
    axes (forward-facing rigs) the range is a multiple of the rig radius."""
    A, b = axes_system(cameras)
    extent = rig_extent(list(cameras))
    converging = axes_converge(cameras)
    out = []
    if converging:
        x = np.linalg.solve(A, b)
        for cam in cameras:
            z = float(cam.world_to_camera(x[None])[0, 2])
            if z > 0:
                out.append((z / C.MVS_DEFAULT_RANGE_FACTOR, z * C.MVS_DEFAULT_RANGE_FACTOR))
            else:
                converging = False
                break
    if not converging:
        out = [(C.MVS_PARALLEL_NEAR_EXTENT * extent, C.MVS_PARALLEL_FAR_EXTENT * extent)] * len(cameras)
    return out
