"""The scene-free estimate of what no train camera sees: a harmonic fill from the observed pixels
around it.

Where no train camera sees a surface, the model's colour there was never supervised: its Gaussians
reach into the region from neighbouring surfaces and carry their texture (an occluder's stripes,
a wall's checks in the wrong phase). Without a generative prior the least-squares estimate of an
unseen patch is smooth, and the smoothest interpolation of the colours around it is the harmonic
function with those colours on its boundary (the membrane of Perez et al.'s Poisson image
editing with a zero guidance field).

Over the pixels no train camera sees, on the demo's validation cameras (demo_val, stage-1 model;
benchmarks/results/restoration_gate_demo_val.json): render 18.59 dB, this fill 19.73, the warp
restorer's output 18.29 (docs/stage2.md section 1b).
"""
from __future__ import annotations

import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import splu

from fixer4d.errors import InputError

# An unobserved pixel is filled where its unobserved weight exceeds this; the fill's result is
# blended in by the weight itself, so observed pixels (weight <= 0.5) come back unchanged.
UNKNOWN_ABOVE = 0.5

_NEIGHBOURS = ((0, 1), (0, -1), (1, 0), (-1, 0))


def harmonic_fill(values: np.ndarray, known: np.ndarray) -> np.ndarray:
    """Values at the known pixels, the harmonic interpolation of them elsewhere.

    values: (H, W, C) float; known: (H, W) bool. Each connected region of unknown pixels
    (4-neighbours) gets the discrete harmonic function whose boundary values are its known
    neighbours, the image border being free (Neumann); it is solved exactly (sparse LU of the
    graph Laplacian: positive definite, since on a connected grid every region of unknown pixels
    touches a known one once any is known). Returns (H, W, C) float32; with nothing known there
    is nothing to interpolate and ``values`` come back as they are.
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
    for dy, dx in _NEIGHBOURS:
        qy, qx = py + dy, px + dx
        inside = (qy >= 0) & (qy < H) & (qx >= 0) & (qx < W)
        p_idx, qy, qx = index[py[inside], px[inside]], qy[inside], qx[inside]
        q_idx = index[qy, qx]
        to_unknown = q_idx >= 0
        rows.append(p_idx[to_unknown])
        cols.append(q_idx[to_unknown])
        diag[p_idx] += 1.0  # p_idx holds each unknown pixel at most once per direction
        rhs[p_idx[~to_unknown]] += out[qy[~to_unknown], qx[~to_unknown]]
    rows, cols = np.concatenate(rows), np.concatenate(cols)
    A = sp.csc_matrix((np.concatenate([diag, -np.ones(rows.size)]),
                       (np.concatenate([np.arange(n), rows]), np.concatenate([np.arange(n), cols]))), shape=(n, n))
    out[unknown] = splu(A).solve(rhs).astype(np.float32)
    return out


def fill_unobserved(rgb: np.ndarray, unobserved: np.ndarray) -> np.ndarray:
    """The clip with its unobserved pixels replaced by the harmonic fill from the observed pixels
    around them, in proportion to how unobserved they are.

    rgb: (F, H, W, 3) render in [0, 1]; unobserved: (F, H, W) in [0, 1]
    (``restore.visibility.unobserved_clip``). The fill's boundary is the observed pixels
    (unobserved <= ``UNKNOWN_ABOVE``); every pixel becomes render + unobserved x (fill - render),
    so an observed pixel, where the fill is the render, comes back unchanged. Returns (F, H, W, 3) float32 in [0, 1].
    """
    rgb = np.clip(np.nan_to_num(np.asarray(rgb, dtype=np.float32), nan=0.0), 0.0, 1.0)
    u = np.clip(np.nan_to_num(np.asarray(unobserved, dtype=np.float32), nan=0.0), 0.0, 1.0)
    if rgb.ndim != 4 or rgb.shape[-1] != 3 or u.shape != rgb.shape[:3]:
        raise InputError(f"fill_unobserved: rgb must be (F, H, W, 3) and unobserved (F, H, W); got {rgb.shape} "
                         f"and {u.shape}")
    out = rgb.copy()
    for f in range(rgb.shape[0]):
        observed = u[f] <= UNKNOWN_ABOVE
        if observed.all():
            continue
        out[f] = rgb[f] + u[f][..., None] * (harmonic_fill(rgb[f], observed) - rgb[f])
    return np.clip(out, 0.0, 1.0)
