"""What a static camera rig itself says about the scene: where it looks, what it sees in common,
and which of its cameras train.

No images, no ground truth: only the cameras' poses and intrinsics. ``rig_focus`` is the point
the optical axes converge on; ``common_view_bounds`` is the volume every camera of the rig sees
(the frustum overlap), with per-camera depth ranges: the scene bounds a capture provides when it
provides none, and the plane sweep's depth range when no SfM points exist. ``select_views``
(``most_separated`` cameras, never the ``centre_camera``) is the default train/held-out split
of every scene layout that has none of its own.
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from fixer4d.errors import InputError
from fixer4d.geometry.camera import Camera, rig_extent

# Optical axes are "converging" when the smallest eigenvalue of sum(I - d d^T) exceeds
# count x sin^2 of this angle's sine: axes closer to parallel than ~3 degrees (sin 0.05) meet
# so far away (or so ill-conditioned) that the meeting point is no focus.
PARALLEL_AXES_SIN = 0.05
# A converging rig sees content up to about as far behind its focus as the cameras stand in
# front of it (the common view of inward-facing cameras closes there): depth samples reach
# this multiple of each camera's distance to the focus.
CONVERGING_FAR_FACTOR = 2.0
# A forward-facing (parallel) rig's frustum overlap never closes: samples stop at this many rig
# radii. Forward-facing captures (LLFF, Neural3DV) frame content within ~5-15 rig radii; the
# sweep is uniform in inverse depth, so a generous far costs few planes.
PARALLEL_FAR_EXTENT = 20.0
# Nearest depth sampled, relative to the farthest: the overlap's near end is found, not
# assumed (the frusta of a rig whose cameras share a view overlap well beyond 1 % of it).
NEAR_SAMPLE_REL = 1e-2
# Samples per image axis and per ray when locating the overlap: 24 x 24 x 64 points per camera
# (~37k) locate its faces to ~4 % of the image and ~7.5 % in depth (geometric steps).
PIXEL_SAMPLES = 24
DEPTH_SAMPLES = 64
# Above this camera count the exhaustive 4-subset search for train views gives way to greedy
# farthest-point sampling (C(30, 4) = 27k subsets is still instant; beyond grows as n^4).
EXHAUSTIVE_TRAIN_SEARCH_MAX = 30


@dataclass(frozen=True)
class ViewBounds:
    """The rig's common view: an axis-aligned box (world units) and, per camera (in the order
    given), the z-depth range (near, far) of the common view in that camera."""

    bbox_min: np.ndarray  # (3,)
    bbox_max: np.ndarray  # (3,)
    depth_ranges: tuple[tuple[float, float], ...]

    @property
    def near(self) -> float:
        return min(r[0] for r in self.depth_ranges)

    @property
    def far(self) -> float:
        return max(r[1] for r in self.depth_ranges)


def axes_system(cameras: Sequence[Camera]) -> tuple[np.ndarray, np.ndarray]:
    """(A (3, 3), b (3,)) of the least-squares point closest to every optical axis:
    sum_i (I - d_i d_i^T) (x - c_i) = 0."""
    A = np.zeros((3, 3))
    b = np.zeros(3)
    for c in cameras:
        P = np.eye(3) - np.outer(c.forward, c.forward)
        A += P
        b += P @ c.center
    return A, b


def axes_converge(cameras: Sequence[Camera]) -> bool:
    """True when the optical axes meet near a point (an inward-facing rig), False for (nearly)
    parallel axes (a forward-facing rig) or fewer than two cameras."""
    if len(cameras) < 2:
        return False
    A, _ = axes_system(cameras)
    return bool(np.linalg.eigvalsh(A)[0] > len(cameras) * PARALLEL_AXES_SIN ** 2)


def rig_focus(cameras: Sequence[Camera], fallback: np.ndarray | None = None) -> np.ndarray:
    """The point the rig looks at (3,): the least-squares closest point to the optical axes when
    they converge in front of the cameras; otherwise ``fallback`` when given, else the centre of
    the rig's common view (a forward-facing rig looks at what all cameras see)."""
    if not cameras:
        raise InputError("rig focus: no cameras")
    if axes_converge(cameras):
        A, b = axes_system(cameras)
        x = np.linalg.solve(A, b)
        if all(float(c.world_to_camera(x[None])[0, 2]) > 0 for c in cameras):
            return x
    if fallback is not None:
        return np.asarray(fallback, np.float64).reshape(3)
    if len(cameras) < 2:
        c = cameras[0]
        return c.center + c.forward
    vb = common_view_bounds(cameras)
    return 0.5 * (vb.bbox_min + vb.bbox_max)


def _far_limits(cameras: Sequence[Camera]) -> list[float]:
    extent = rig_extent(list(cameras))
    if axes_converge(cameras):
        A, b = axes_system(cameras)
        x = np.linalg.solve(A, b)
        z = [float(c.world_to_camera(x[None])[0, 2]) for c in cameras]
        if min(z) > 0:
            return [CONVERGING_FAR_FACTOR * zi for zi in z]
    return [PARALLEL_FAR_EXTENT * extent] * len(cameras)


def common_view_bounds(cameras: Sequence[Camera]) -> ViewBounds:
    """The volume every camera sees (frustum overlap), sampled along each camera's rays.

    Each camera casts PIXEL_SAMPLES^2 rays over its image at DEPTH_SAMPLES depths (geometric,
    NEAR_SAMPLE_REL x far .. far; far from ``_far_limits``); points inside every image and in
    front of every camera form the common view. Raises InputError when there is none.
    """
    cameras = list(cameras)
    if not cameras:
        raise InputError("common view: no cameras")
    fars = _far_limits(cameras)
    kept = []
    for cam, far in zip(cameras, fars):
        u = (np.arange(PIXEL_SAMPLES) + 0.5) / PIXEL_SAMPLES * cam.width
        v = (np.arange(PIXEL_SAMPLES) + 0.5) / PIXEL_SAMPLES * cam.height
        uv = np.stack(np.meshgrid(u, v), -1).reshape(-1, 2)
        zs = np.geomspace(NEAR_SAMPLE_REL * far, far, DEPTH_SAMPLES)
        uvz = np.repeat(uv, len(zs), 0)
        z = np.tile(zs, len(uv))
        pts = cam.backproject(uvz, z)
        seen = np.ones(len(pts), bool)
        for other in cameras:
            p, zo = other.project(pts)
            with np.errstate(invalid="ignore"):
                seen &= ((zo > 0) & (p[:, 0] >= 0) & (p[:, 0] <= other.width)
                         & (p[:, 1] >= 0) & (p[:, 1] <= other.height))
        kept.append(pts[seen])
    pts = np.concatenate(kept)
    if pts.shape[0] == 0:
        raise InputError(f"the {len(cameras)} cameras share no common view (their frusta do not overlap); "
                         f"check the poses or choose cameras that see the same scene")
    ranges = []
    for cam in cameras:
        z = cam.world_to_camera(pts)[:, 2]
        ranges.append((float(z.min()), float(z.max())))
    return ViewBounds(pts.min(0), pts.max(0), tuple(ranges))


def centre_camera(cameras: list[Camera]) -> int:
    """Index of the camera closest to the rig's centroid (the held-out centre view)."""
    centers = np.stack([c.center for c in cameras])
    return int(np.argmin(np.linalg.norm(centers - centers.mean(0), axis=1)))


def most_separated(cameras: list[Camera], k: int = 4, exclude: tuple[int, ...] = ()) -> list[int]:
    """The ``k`` cameras whose centres are most spread out: the subset maximizing the smallest
    pairwise distance, ties broken by the largest distance sum, then the lowest indices.
    Cameras in ``exclude`` (the centre view) are never picked. Sorted indices."""
    centers = np.stack([c.center for c in cameras])
    pool = [i for i in range(len(cameras)) if i not in exclude]
    if len(pool) < k:
        raise InputError(f"need at least {k} cameras to choose the train views, the rig has {len(pool)} eligible")
    D = np.linalg.norm(centers[:, None] - centers[None], axis=-1)
    if len(pool) <= EXHAUSTIVE_TRAIN_SEARCH_MAX:
        combos = np.array(list(itertools.combinations(pool, k)))
        pairs = np.array(list(itertools.combinations(range(k), 2)))
        dist = D[combos[:, pairs[:, 0]], combos[:, pairs[:, 1]]]
        # Round so float noise between mirror-symmetric subsets does not decide the winner.
        key_min = np.round(dist.min(1), 9)
        key_sum = np.round(dist.sum(1), 9)
        order = np.lexsort((key_sum, key_min))[::-1]
        best_min, best_sum = key_min[order[0]], key_sum[order[0]]
        tied = [i for i in range(len(combos)) if key_min[i] == best_min and key_sum[i] == best_sum]
        return sorted(int(x) for x in combos[min(tied)])
    chosen = [pool[int(np.argmax(D[pool][:, pool].sum(1)))]]
    while len(chosen) < k:
        rest = [i for i in pool if i not in chosen]
        chosen.append(rest[int(np.argmax(D[rest][:, chosen].min(1)))])
    return sorted(chosen)


def select_views(cameras: list[Camera], train: Any = "auto", where: str = "<spec>",
                 test: Any = None) -> tuple[list[int], list[int]]:
    """(train_ids, test_ids): ``train`` = "auto" (the 4 most separated cameras, never the centre
    one, which is held out) or a list of camera indices; ``test`` = None (every other camera) or
    a list of camera indices disjoint from the train ones (cameras in neither are not used)."""
    n = len(cameras)
    if train in (None, "auto"):
        if n < 2:
            raise InputError(f"scene spec {where}: rig: a rig needs at least 2 cameras (train + held out), got {n}")
        # Rigs of 4 cameras or fewer still hold the centre one out, training on the rest.
        train_ids = most_separated(cameras, min(4, n - 1), exclude=(centre_camera(cameras),))
    else:
        train_ids = _camera_indices(train, n, f"scene spec {where}: rig.train", '"auto" or ')
    if test is None:
        return train_ids, [i for i in range(n) if i not in train_ids]
    test_ids = _camera_indices(test, n, f"scene spec {where}: rig.test")
    both = sorted(set(test_ids) & set(train_ids))
    if both or not test_ids:
        raise InputError(f"scene spec {where}: rig.test: needs at least one camera and none of the train ones"
                         + (f" (both: {both})" if both else ""))
    return train_ids, test_ids


def _camera_indices(value: Any, n: int, where: str, alternative: str = "") -> list[int]:
    """``value`` as sorted camera indices in [0, n), or an InputError naming ``where``."""
    try:
        ids = sorted(int(i) for i in value)
    except (TypeError, ValueError):
        raise InputError(f"{where}: {alternative}a list of camera indices, got {value!r}") from None
    bad = [i for i in ids if not 0 <= i < n]
    if bad:
        raise InputError(f"{where}: camera indices {bad} outside [0, {n})")
    return ids
