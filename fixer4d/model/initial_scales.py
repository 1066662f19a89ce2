"""Initial spatial and temporal extents of Gaussians placed on a point cloud.

Spatial: 3DGS's rule, the root mean squared distance to the 3 nearest neighbours (isotropic).
Temporal: the spacing of the cloud's point times (one frame when every frame has a cloud).
``point_scales`` and ``point_temporal_std`` take an explicit value instead when one is given,
and check either (``SpacetimeGaussians.from_points``).
"""
from __future__ import annotations

import math

import numpy as np

from fixer4d.errors import InputError

# 3DGS floors the squared mean 3-NN distance at 1e-7 so that duplicate points still get a
# positive, trainable scale.
KNN_DIST2_FLOOR = 1e-7
# Number of neighbours whose distances set the initial scale (3DGS).
KNN_NEIGHBOURS = 3
# A cloud of one point has no neighbour to measure; 0.01 is ~1% of a unit-scale scene.
SINGLE_POINT_SCALE = 0.01

# Initial temporal std in units of the init cloud spacing (the median gap between distinct point
# times, i.e. one frame when every frame has a cloud, k frames when every k-th frame has one).
# At 1 spacing a Gaussian keeps exp(-0.25) = 78% of its opacity halfway to the next cloud (so
# consecutive clouds overlap and no instant between them is empty) and fades to exp(-4) < 2% two
# clouds away (so a moving object leaves little ghosting before the optimizer adapts s_t).
INIT_TEMPORAL_SPACINGS = 1.0
# With points at a single time there is no spacing; the Gaussians should then cover the clip
# (t in [0, 1)): a temporal std of 1 keeps >= exp(-1) = 37% opacity across it.
SINGLE_TIME_TEMPORAL_STD = 1.0


def knn_scales(points: np.ndarray) -> np.ndarray:
    """Isotropic initial scales (N,) = sqrt(mean squared distance to the 3 nearest neighbours)."""
    from scipy.spatial import cKDTree

    n = points.shape[0]
    if n == 0:
        return np.zeros(0)
    if n == 1:
        return np.full(1, SINGLE_POINT_SCALE)
    k = min(KNN_NEIGHBOURS, n - 1)
    dist, _ = cKDTree(points).query(points, k=k + 1, workers=-1)
    d2 = np.mean(np.asarray(dist).reshape(n, k + 1)[:, 1:] ** 2, axis=1)
    return np.sqrt(np.maximum(d2, KNN_DIST2_FLOOR))


def initial_temporal_std(times: np.ndarray) -> float:
    """Initial temporal std from the point times' spacing (see INIT_TEMPORAL_SPACINGS)."""
    uniq = np.unique(times)
    if uniq.size < 2:
        return SINGLE_TIME_TEMPORAL_STD
    return float(INIT_TEMPORAL_SPACINGS * np.median(np.diff(uniq)))


def point_scales(points: np.ndarray, scales: np.ndarray | None) -> np.ndarray:
    """(N, 3) float64 std devs of Gaussians on ``points`` (N, 3): ``scales`` ((N,) isotropic or
    (N, 3)) when given, else ``knn_scales``; InputError for non-positive, non-finite or
    mis-sized scales."""
    n = points.shape[0]
    if scales is None:
        with np.errstate(over="ignore", invalid="ignore"):
            sc = np.repeat(knn_scales(points)[:, None], 3, axis=1)
        if not np.all(np.isfinite(sc)):
            raise InputError("from_points: the points' nearest-neighbour distances overflow; rescale the scene "
                             "to unit order (or pass scales)")
        return sc
    try:
        sc = np.asarray(scales, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"from_points: scales must be {n} positive finite numbers (or rows of 3)") from None
    sc = np.repeat(sc.reshape(-1, 1), 3, axis=1) if sc.ndim == 1 else sc.reshape(-1, 3)
    if sc.shape[0] != n or not np.all(np.isfinite(sc)) or np.any(sc <= 0):
        raise InputError(f"from_points: scales must be {n} positive finite values (or rows of 3)")
    return sc


def point_temporal_std(times: np.ndarray, t_scale: float | None) -> float:
    """Temporal std (clip time units) of Gaussians born at ``times`` (N,): ``t_scale`` when
    given, else ``initial_temporal_std``; InputError unless it is positive and finite."""
    if t_scale is None:
        with np.errstate(over="ignore", invalid="ignore"):
            std_t = initial_temporal_std(times)
        if not (std_t > 0 and math.isfinite(std_t)):
            raise InputError(f"from_points: the spacing of the point times ({std_t}) is no usable temporal std; "
                             "pass t_scale or times in clip units")
        return std_t
    try:
        std_t = float(t_scale)
    except (TypeError, ValueError):
        std_t = math.nan
    if not (std_t > 0 and math.isfinite(std_t)):
        raise InputError(f"from_points: t_scale must be positive and finite, got {t_scale!r}")
    return std_t
