"""Choosing k of N init points: a seeded uniform draw, a stratified one, or an even spread in space.

A dense MVS init has 10-20x more points than the Gaussian budget takes (the demo: ~280k fused
points for 15k Gaussians), so which points are kept is decided here. ``random`` draws them
uniformly with the run's seed: the kept set changes with the seed, and the draw keeps the dense
regions dense (a textured wall near the rig) and the sparse ones sparse. ``stratified`` keeps the
density too, with less of the seed's luck: the points are put in Z-order (Morton order of their
grid cells, group by group) and cut into k runs of N/k consecutive points, and one point is drawn
from each run; a region keeps its share of the cloud to within the runs its boundary cuts, where a
uniform draw's share varies by its binomial spread. ``spatial`` keeps one point per cell of the coarsest
grid that has at least k occupied cells, the point nearest its cell's centre: the same points for
every seed, and every region the cloud reaches keeps some.
"""
from __future__ import annotations

import numpy as np

#: How the init points are chosen when a cloud has more than the budget (TrainingConfig.init_subsample).
INIT_SUBSAMPLES = ("random", "stratified", "spatial")

# Bisection steps on the cell size (log scale between twice the cloud's extent and 1e-6 of it, a
# factor of 2e6): each halves the log of the bracket's ratio, so 24 steps leave a ratio of
# 1 + 1e-6, far finer than any two grids that differ in their occupied cells; one step is one
# sort of the N cell keys.
_BISECTION_STEPS = 24
# The smallest cell tried, relative to the cloud's extent: below the precision of a float32 point.
_MIN_CELL_REL = 1e-6
# The fixed seed of the choice among surplus cells (the grid with >= k cells has a few more than
# k): fixed, so the kept set does not depend on the run's seed.
_SURPLUS_SEED = 0
# Bits per axis of the Z-order's grid: 3 x 21 = 63 bits fill one int64 key, and 2^21 cells per
# axis resolve a 100 m scene to 0.05 mm, far below any two MVS points' spacing.
_MORTON_BITS = 21


def subsample(points: np.ndarray, k: int, method: str, rng: np.random.Generator,
              groups: np.ndarray | None = None) -> np.ndarray:
    """Sorted indices of at most ``k`` rows of ``points`` (N, 3); all N when N <= k.

    method: ``random`` (``rng``'s uniform draw without replacement), ``stratified``
    (``stratified_subsample`` with ``rng``) or ``spatial`` (``spatial_subsample``; ``rng`` unused).
    groups: (N,) integer labels whose points never share a cell (the frame of a moving point: two
    frames' points at one place are two Gaussians)."""
    n = int(points.shape[0])
    if n <= k:
        return np.arange(n)
    if k <= 0:
        return np.zeros(0, dtype=np.int64)
    if method == "random":
        return np.sort(rng.choice(n, size=k, replace=False))
    if method == "stratified":
        return stratified_subsample(points, k, rng, groups)
    if method == "spatial":
        return spatial_subsample(points, k, groups)
    raise ValueError(f"init subsample {method!r}: choose one of {list(INIT_SUBSAMPLES)}")


def stratified_subsample(points: np.ndarray, k: int, rng: np.random.Generator,
                         groups: np.ndarray | None = None) -> np.ndarray:
    """Sorted indices of ``k`` rows of ``points`` (N, 3), N > k >= 1: one uniform draw from each of
    k runs of consecutive points in Z-order (sorted by group, then Morton key, then index).

    Run i holds the points at ranks floor(i N / k) .. floor((i + 1) N / k) - 1, at least one since
    N > k. Any region that is a union of Z-order runs keeps exactly its proportional share, and any
    box keeps it to within the runs its boundary cuts: the draw keeps the cloud's density (its
    confidence) as ``random`` does, without the binomial spread of that share over seeds."""
    pts = np.asarray(points, dtype=np.float64)
    n = pts.shape[0]
    g = np.zeros(n, dtype=np.int64) if groups is None else np.asarray(groups).astype(np.int64)
    order = np.lexsort((np.arange(n), morton_keys(pts), g))
    starts = (np.arange(k + 1, dtype=np.int64) * n) // k
    picks = starts[:-1] + np.floor(rng.random(k) * np.diff(starts)).astype(np.int64)
    return np.sort(order[picks])


def morton_keys(points: np.ndarray) -> np.ndarray:
    """(N,) int64 Z-order key of each row of ``points`` (N, 3): its cell in a 2^21-per-axis grid
    over the cloud's bounding cube, the three cell indices' bits interleaved (x lowest). Non-finite
    or coincident clouds give key 0 for every point."""
    pts = np.asarray(points, dtype=np.float64)
    lo = pts.min(axis=0) if pts.size else np.zeros(3)
    extent = float(np.max(pts.max(axis=0) - lo)) if pts.size else 0.0
    if not np.isfinite(extent) or extent <= 0.0:
        return np.zeros(pts.shape[0], dtype=np.int64)
    top = (1 << _MORTON_BITS) - 1
    cells = np.clip(np.floor((pts - lo) / extent * top), 0, top).astype(np.int64)
    key = np.zeros(pts.shape[0], dtype=np.int64)
    for bit in range(_MORTON_BITS):
        for axis in range(3):
            key |= ((cells[:, axis] >> bit) & 1) << (3 * bit + axis)
    return key


def spatial_subsample(points: np.ndarray, k: int, groups: np.ndarray | None = None) -> np.ndarray:
    """Sorted indices of ``k`` rows of ``points`` (N, 3), N > k >= 1, spread evenly in space.

    Finds by bisection the largest cubic cell size whose grid (anchored at the cloud's minimum
    corner) has at least k occupied cells (per group), keeps in each cell the point nearest the
    cell's centre (ties: the lower index), and, where that gives more than k, drops surplus cells
    by a fixed-seed draw. Duplicated points can leave fewer than k distinct cells even at the
    smallest size; the rest is then filled with the lowest indices not yet kept. Deterministic:
    the same points give the same indices."""
    pts = np.asarray(points, dtype=np.float64)
    n = pts.shape[0]
    g = np.zeros(n, dtype=np.int64) if groups is None else np.asarray(groups).astype(np.int64)
    lo = pts.min(axis=0)
    extent = float(np.max(pts.max(axis=0) - lo))
    if not np.isfinite(extent) or extent <= 0.0:  # every point at one place
        return np.arange(k)
    rel = pts - lo
    small, large = extent * _MIN_CELL_REL, extent * 2.0
    if _occupied(rel, g, small)[1] < k:
        keep = _representatives(rel, g, small)
        rest = np.setdiff1d(np.arange(n), keep)[: k - keep.size]
        return np.sort(np.concatenate([keep, rest]))
    for _ in range(_BISECTION_STEPS):  # invariant: >= k cells at `small`, < k at `large`
        mid = float(np.sqrt(small * large))
        if _occupied(rel, g, mid)[1] >= k:
            small = mid
        else:
            large = mid
    keep = _representatives(rel, g, small)
    if keep.size > k:
        keep = np.random.default_rng(_SURPLUS_SEED).choice(keep, size=k, replace=False)
    return np.sort(keep)


def _cells(rel: np.ndarray, groups: np.ndarray, size: float) -> np.ndarray:
    """(N, 4) integer cell of each point: its group and its grid index at cell ``size``."""
    return np.concatenate([groups[:, None], np.floor(rel / size).astype(np.int64)], axis=1)


def _occupied(rel: np.ndarray, groups: np.ndarray, size: float) -> tuple[np.ndarray, int]:
    """(inverse (N,): each point's cell number, numbered in the order of the cells, number of
    occupied cells) at cell ``size``."""
    cells = _cells(rel, groups, size)
    cells -= cells.min(axis=0)
    dims = cells.max(axis=0) + 1
    if float(np.prod(dims.astype(np.float64))) < 2.0 ** 62:  # one int64 key per cell: a 1-D sort
        key = np.ravel_multi_index(tuple(cells.T), tuple(int(d) for d in dims))
        order = np.argsort(key, kind="stable")
        sorted_key = key[order]
    else:
        order = np.lexsort(cells.T[::-1])
        sorted_key = cells[order]
    new = np.ones(order.size, dtype=bool)
    new[1:] = np.any((sorted_key[1:] != sorted_key[:-1]).reshape(order.size - 1, -1), axis=1)
    inverse = np.empty(order.size, dtype=np.int64)
    inverse[order] = np.cumsum(new) - 1
    return inverse, int(new.sum())


def _representatives(rel: np.ndarray, groups: np.ndarray, size: float) -> np.ndarray:
    """Per occupied cell at ``size``, the index of the point nearest the cell's centre (ties: lower index)."""
    cells = _cells(rel, groups, size)
    centre = (cells[:, 1:].astype(np.float64) + 0.5) * size
    dist = np.sum((rel - centre) ** 2, axis=1)
    inverse, _ = _occupied(rel, groups, size)
    order = np.lexsort((np.arange(rel.shape[0]), dist, inverse))  # by cell, then distance, then index
    first = np.ones(order.size, dtype=bool)
    first[1:] = inverse[order[1:]] != inverse[order[:-1]]
    return order[first]
