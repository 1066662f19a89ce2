"""Level of detail for moving frames: which splats to draw when only a fraction fits the budget.

On a software GL (Mesa llvmpipe) a splat frame at reduced resolution costs about 3 us per splat
(triangle setup and binning run on one thread; measured on the demo's 30k-splat surfaces at
196x108: 30k -> 180 ms, 8k -> 60 ms, 4k -> 19 ms, load ~4), so while the camera moves or time
plays the view draws a subset and the full set once the view rests.

The subset is deterministic and nested: every Gaussian gets a rank once per Gaussian set
(weighted random sampling without replacement, Efraimidis-Spirakis keys u^(1/w) with u a stable
hash of the Gaussian's index and w its peak opacity), and a fraction f draws the Gaussians of
rank < f N. Ranks by a hash spread the subset evenly over the scene (a surface thins out instead
of losing whole regions), the opacity weight drops faint Gaussians first, and a larger fraction
only adds splats, so the image does not flicker as the fraction changes. The projected area is
left out of the weight: it depends on the view, and world area alone favours far splats over
near ones of the same screen size (a back-projected surface's splats grow with depth).

The kept splats stand in for the dropped ones around them: their 2D covariance is scaled by
1/f (``area_factor``), so the drawn surface keeps its coverage (in expectation) at a coarser
grain.
"""
from __future__ import annotations

import numpy as np

# Weight floor: a Gaussian of (near) zero peak opacity still gets a finite key (it goes last).
_WEIGHT_MIN = 1e-6


def stable_uniform(n: int) -> np.ndarray:
    """(n,) float64 in (0, 1): a fixed hash (splitmix64 finaliser) of each index 0..n-1, so a
    Gaussian keeps its draw across frames, runs and edits that keep its index."""
    with np.errstate(over="ignore"):
        z = np.arange(n, dtype=np.uint64) + np.uint64(0x9E3779B97F4A7C15)
        z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
        z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
        z = z ^ (z >> np.uint64(31))
    return ((z >> np.uint64(11)).astype(np.float64) + 0.5) / float(1 << 53)


def importance_rank(opacity_logits: np.ndarray) -> np.ndarray:
    """(N,) int64 rank of each Gaussian in the level-of-detail order (0 = drawn first), from the
    (N,) opacity logits (peak opacity sigmoid(logit) is the sampling weight)."""
    logits = np.asarray(opacity_logits, np.float64).reshape(-1)
    n = logits.size
    w = np.maximum(1.0 / (1.0 + np.exp(-logits)), _WEIGHT_MIN)
    key = np.log(stable_uniform(n)) / w  # = log(u^(1/w)): larger keys go first
    order = np.argsort(-key, kind="stable")
    rank = np.empty(n, np.int64)
    rank[order] = np.arange(n)
    return rank


def lod_count(n: int, fraction: float) -> int:
    """Splats drawn of ``n`` at ``fraction`` (at least 1 when n > 0)."""
    if n <= 0:
        return 0
    return int(min(n, max(1, int(np.ceil(float(fraction) * n)))))


def lod_subset(order: np.ndarray, rank: np.ndarray, count: int) -> np.ndarray:
    """The entries of a depth ``order`` (indices, front to back) whose rank is below ``count``,
    still front to back."""
    order = np.asarray(order)
    return order[rank[order] < count]


def area_factor(n: int, count: int) -> float:
    """Scale of the 2D covariance of each kept splat: n / count (1 when all are drawn)."""
    return 1.0 if count <= 0 or count >= n else float(n) / float(count)
