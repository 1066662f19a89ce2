"""The scene-free estimate of what no train camera sees: a harmonic fill from the observed pixels
around it.

Where no train camera sees a surface, the model's colour there was never supervised: its Gaussians
reach into the region from neighbouring surfaces and carry their texture (an occluder's stripes,
a wall's checks in the wrong phase). Without a generative prior the least-squares estimate of an
unseen patch is smooth, and the smoothest interpolation of the colours around it is the harmonic
function with those colours on its boundary (the membrane of Perez et al.'s Poisson image
editing with a zero guidance field).

Most unseen pixels of a novel view are disocclusions: the view looks behind something the train
cameras see in front of it, so the unseen colour continues the background around the region, not
the occluder's edge (the rule of hole filling in depth-image-based rendering). With the render's
depth the fill takes its boundary colours from the pixels at or behind the region's depth
(``background_boundary_weights``); an occluder's edge constrains it only weakly.

Over all pixels of the validation cameras, stage-1 models, the Restoration rows' clips
(benchmarks/restoration_gate.py; docs/decisions/background-fill.md): render / plain fill / this fill
17.82 / 20.94 / 21.09 dB on Panoptic 4/14, 19.81 / 20.50 / 20.53 on split c 2/12, 25.15 / 25.22 /
25.22 on demo_val.
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy import ndimage
from scipy.sparse.linalg import splu

from fixer4d.errors import InputError

# An unobserved pixel is filled where its unobserved weight exceeds this; the fill's result is
# blended in by the weight itself, so observed pixels (weight <= 0.5) come back unchanged.
UNKNOWN_ABOVE = 0.5

_NEIGHBOURS = ((0, 1), (0, -1), (1, 0), (-1, 0))

# How far in front of an unseen pixel (relative depth) a boundary pixel may be and still give it
# its colour: a boundary pixel (ref - d) / ref in front of it weighs exp(-that / tol). Chosen on
# the validation cameras among 0.02, 0.05, 0.1 and 0.2 (docs/decisions/background-fill.md): the largest
# mean gain over the plain fill whose worst camera set stays within 0.01 dB of it (0.02 and 0.05
# gain most on the real folders, +0.19 / +0.09 and +0.17 / +0.06 dB, but cost demo_val 0.02 and
# 0.01 dB; 0.1: +0.15 / +0.03, demo_val -0.004).
BACKGROUND_DEPTH_TOL = 0.1
# A render pixel with at least this alpha has a surface whose depth is its own (below: a hole).
SURFACE_ALPHA = 0.5
# The least weight of a boundary pixel: a region walled in by an occluder alone still takes its
# colours from it (and the system stays positive definite).
MIN_BOUNDARY_WEIGHT = 1e-4


def harmonic_fill(values: np.ndarray, known: np.ndarray, boundary_weight: np.ndarray | None = None) -> np.ndarray:
    """Values at the known pixels, the harmonic interpolation of them elsewhere.

    values: (H, W, C) float; known: (H, W) bool. Each connected region of unknown pixels
    (4-neighbours) gets the discrete harmonic function whose boundary values are its known
    neighbours, the image border being free (Neumann); it is solved exactly (sparse LU of the
    graph Laplacian: positive definite, since on a connected grid every region of unknown pixels
    touches a known one once any is known). boundary_weight: (4, H, W) > 0, the conductance of
    the link from each unknown pixel to its neighbour in ``_NEIGHBOURS`` order where that
    neighbour is known (default 1: the plain membrane). Returns (H, W, C) float32; with nothing
    known there is nothing to interpolate and ``values`` come back as they are.
    """
    values = np.asarray(values, dtype=np.float32)
    known = np.asarray(known, dtype=bool)
    if values.ndim != 3 or known.shape != values.shape[:2]:
        raise InputError(f"harmonic_fill: values must be (H, W, C) and known (H, W), got {values.shape} "
                         f"and {known.shape}")
    out = np.nan_to_num(values, nan=0.0).astype(np.float32)
    unknown = ~known
    if not unknown.any() or not known.any():
        return out
    H, W, C = out.shape
    n = int(unknown.sum())
    index = np.full((H, W), -1, dtype=np.int64)
    index[unknown] = np.arange(n)
    py, px = np.nonzero(unknown)
    diag = np.zeros(n)
    rhs = np.zeros((n, C))
    rows, cols = [], []
    for k, (dy, dx) in enumerate(_NEIGHBOURS):
        qy, qx = py + dy, px + dx
        inside = (qy >= 0) & (qy < H) & (qx >= 0) & (qx < W)
        p_idx, qy, qx = index[py[inside], px[inside]], qy[inside], qx[inside]
        q_idx = index[qy, qx]
        to_unknown = q_idx >= 0
        rows.append(p_idx[to_unknown])
        cols.append(q_idx[to_unknown])
        w = np.ones(p_idx.size)
        if boundary_weight is not None:
            w[~to_unknown] = boundary_weight[k][py[inside][~to_unknown], px[inside][~to_unknown]]
        diag[p_idx] += w  # p_idx holds each unknown pixel at most once per direction
        rhs[p_idx[~to_unknown]] += w[~to_unknown, None] * out[qy[~to_unknown], qx[~to_unknown]]
    rows, cols = np.concatenate(rows), np.concatenate(cols)
    A = sp.csc_matrix((np.concatenate([diag, -np.ones(rows.size)]),
                       (np.concatenate([np.arange(n), rows]), np.concatenate([np.arange(n), cols]))), shape=(n, n))
    out[unknown] = splu(A).solve(rhs).astype(np.float32)
    return out


def background_boundary_weights(depth: np.ndarray, known: np.ndarray, surface: np.ndarray,
                                tol: float = BACKGROUND_DEPTH_TOL) -> np.ndarray:
    """(4, H, W) ``harmonic_fill`` boundary weights that let the background fill an unseen region.

    depth: (H, W) render depth (<= 0 or non-finite: none); known: (H, W) bool; surface: (H, W)
    bool, where the render has a surface (alpha >= SURFACE_ALPHA). An unknown pixel's reference
    depth is its own surface depth, or for a hole (no surface) the farthest known depth around its
    region; the link to a known neighbour that is (ref - d) / ref in front of it weighs
    exp(-that / tol), one at or behind it 1, one without a depth 1, never less than
    MIN_BOUNDARY_WEIGHT.
    """
    if not tol > 0:
        raise InputError(f"background_boundary_weights: tol must be > 0, got {tol}")
    depth = np.where(np.isfinite(depth) & (depth > 0), depth, 0.0).astype(np.float64)
    unknown = ~np.asarray(known, dtype=bool)
    H, W = depth.shape
    weights = np.ones((len(_NEIGHBOURS), H, W), np.float32)
    if not unknown.any():
        return weights
    labels, n = ndimage.label(unknown)
    py, px = np.nonzero(unknown)
    links = []
    farthest = np.zeros(n + 1)
    for dy, dx in _NEIGHBOURS:
        qy, qx = py + dy, px + dx
        inside = (qy >= 0) & (qy < H) & (qx >= 0) & (qx < W)
        qy, qx = np.where(inside, qy, 0), np.where(inside, qx, 0)
        boundary = inside & ~unknown[qy, qx] & (depth[qy, qx] > 0)
        links.append((qy, qx, boundary))
        np.maximum.at(farthest, labels[py[boundary], px[boundary]], depth[qy[boundary], qx[boundary]])
    own = depth[py, px]
    ref = np.where(surface[py, px] & (own > 0), own, farthest[labels[py, px]])
    for k, (qy, qx, boundary) in enumerate(links):
        front = np.zeros(py.size)
        ok = boundary & (ref > 0)
        front[ok] = np.maximum(0.0, (ref[ok] - depth[qy[ok], qx[ok]]) / ref[ok])
        weights[k][py, px] = np.maximum(np.exp(-front / tol), MIN_BOUNDARY_WEIGHT)
    return weights


def fill_unobserved(rgb: np.ndarray, unobserved: np.ndarray, depth: np.ndarray | None = None,
                    alpha: np.ndarray | None = None, tol: float = BACKGROUND_DEPTH_TOL) -> np.ndarray:
    """The clip with its unobserved pixels replaced by the harmonic fill from the observed pixels
    around them, in proportion to how unobserved they are.

    rgb: (F, H, W, 3) render in [0, 1]; unobserved: (F, H, W) in [0, 1]
    (``restore.visibility.unobserved_clip``). The fill's boundary is the observed pixels
    (unobserved <= ``UNKNOWN_ABOVE``); every pixel becomes render + unobserved x (fill - render),
    so an observed pixel, where the fill is the render, comes back unchanged. depth, alpha:
    (F, H, W) render depth and alpha: the boundary weighs the background
    (``background_boundary_weights`` with ``tol``); without them every boundary pixel weighs the same.
    Returns (F, H, W, 3) float32 in [0, 1].
    """
    rgb = np.clip(np.nan_to_num(np.asarray(rgb, dtype=np.float32), nan=0.0), 0.0, 1.0)
    u = np.clip(np.nan_to_num(np.asarray(unobserved, dtype=np.float32), nan=0.0), 0.0, 1.0)
    if rgb.ndim != 4 or rgb.shape[-1] != 3 or u.shape != rgb.shape[:3]:
        raise InputError(f"fill_unobserved: rgb must be (F, H, W, 3) and unobserved (F, H, W); got {rgb.shape} "
                         f"and {u.shape}")
    if (depth is None) != (alpha is None) or (depth is not None and (np.shape(depth) != u.shape
                                                                       or np.shape(alpha) != u.shape)):
        raise InputError(f"fill_unobserved: depth and alpha go together, each (F, H, W) = {u.shape}")
    out = rgb.copy()
    for f in range(rgb.shape[0]):
        observed = u[f] <= UNKNOWN_ABOVE
        if observed.all():
            continue
        weights = None if depth is None else background_boundary_weights(
            depth[f], observed, np.nan_to_num(alpha[f], nan=0.0) >= SURFACE_ALPHA, tol)
        out[f] = rgb[f] + u[f][..., None] * (harmonic_fill(rgb[f], observed, weights) - rgb[f])
    return np.clip(out, 0.0, 1.0)
