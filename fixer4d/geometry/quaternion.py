"""Unit quaternions in (w, x, y, z) order, float64 numpy (docs/design.md §4), plus the one torch
quaternion->matrix that the renderer and densification share (``to_matrix_torch``).

Every function that consumes a quaternion normalizes it first; a zero (or non-finite-norm)
quaternion maps to the identity rather than to NaN.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:  # torch is imported by to_matrix_torch's caller; geometry stays numpy-only to import
    import torch

# Below this norm a quaternion carries no rotation we can trust; treat it as the identity.
_ZERO_NORM = 1e-12
# Above this cosine two unit quaternions are so close that SLERP's sin(theta) denominator loses
# all precision; linear interpolation + renormalization is exact to float64 there.
_SLERP_LINEAR_COS = 1.0 - 1e-10


def normalize(q: np.ndarray) -> np.ndarray:
    """Normalize quaternions (..., 4); zero or non-finite ones become the identity (1, 0, 0, 0)."""
    q = np.asarray(q, dtype=np.float64)
    n = np.linalg.norm(q, axis=-1, keepdims=True)
    bad = ~np.isfinite(n) | (n < _ZERO_NORM)
    safe = np.where(bad, 1.0, n)
    out = q / safe
    ident = np.zeros_like(q)
    ident[..., 0] = 1.0
    return np.where(bad, ident, out)


def to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) from quaternions (..., 4) (normalized first)."""
    w, x, y, z = np.moveaxis(normalize(q), -1, 0)
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], -2)


def to_matrix_torch(q: "torch.Tensor") -> "torch.Tensor":
    """Rotation matrices (..., 3, 3) from quaternions (..., 4) as torch tensors, differentiable.

    Normalized here; a quaternion with norm <= ``_ZERO_NORM`` or a non-finite norm maps to the
    identity (as ``normalize`` does) with a zero, finite gradient: both ``torch.where`` branches stay finite, so no NaN leaks into backward.
    Same dtype and device as ``q``. Used by the rasterizer's projection and by densification.
    """
    import torch  # lazily: importing fixer4d.geometry must not pull in torch

    norm = q.norm(dim=-1, keepdim=True)
    ok = (norm > _ZERO_NORM) & torch.isfinite(norm)
    identity = torch.zeros_like(q)
    identity[..., 0] = 1.0
    qn = torch.where(ok, q / torch.where(ok, norm, torch.ones_like(norm)), identity)
    w, x, y, z = qn.unbind(-1)
    entries = [
        1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
        2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
        2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
    ]
    return torch.stack(entries, -1).reshape(*q.shape[:-1], 3, 3)


def from_matrix(R: np.ndarray) -> np.ndarray:
    """Quaternions (..., 4) with w >= 0 from rotation matrices (..., 3, 3).

    Shepperd's method: pick the largest of (trace, R00, R11, R22) as the pivot so the square
    root argument is never near zero; exact for 180-degree rotations too.
    """
    R = np.asarray(R, dtype=np.float64)
    batch = R.shape[:-2]
    R = R.reshape(-1, 3, 3)
    q = np.empty((R.shape[0], 4))
    tr = np.trace(R, axis1=1, axis2=2)
    diag = np.diagonal(R, axis1=1, axis2=2)
    pivot = np.argmax(np.concatenate([tr[:, None], diag], 1), axis=1)
    for k in range(R.shape[0]):
        m = R[k]
        p = pivot[k]
        if p == 0:
            s = 2.0 * np.sqrt(max(1.0 + tr[k], 0.0))
            q[k] = [0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s]
        elif p == 1:
            s = 2.0 * np.sqrt(max(1.0 + m[0, 0] - m[1, 1] - m[2, 2], 0.0))
            q[k] = [(m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s]
        elif p == 2:
            s = 2.0 * np.sqrt(max(1.0 + m[1, 1] - m[0, 0] - m[2, 2], 0.0))
            q[k] = [(m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s]
        else:
            s = 2.0 * np.sqrt(max(1.0 + m[2, 2] - m[0, 0] - m[1, 1], 0.0))
            q[k] = [(m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s]
    q = np.where(q[:, :1] < 0, -q, q)
    return normalize(q).reshape(*batch, 4)


def multiply(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product a * b for (..., 4) quaternions (not normalized)."""
    aw, ax, ay, az = np.moveaxis(np.asarray(a, np.float64), -1, 0)
    bw, bx, by, bz = np.moveaxis(np.asarray(b, np.float64), -1, 0)
    return np.stack([
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    ], -1)


def slerp(q0: np.ndarray, q1: np.ndarray, alpha: float | np.ndarray) -> np.ndarray:
    """Spherical linear interpolation between unit quaternions along the shorter arc.

    ``alpha`` may be a scalar or an array (A,); the result is (4,) or (A, 4). The result equals
    normalize(q0) at alpha = 0 and ±normalize(q1) at alpha = 1 exactly (the sign of q1 is
    flipped when needed to take the short way; both signs are the same rotation).
    Identical and nearly identical inputs fall back to normalized lerp; antipodal inputs
    (q1 = -q0) are the same rotation and interpolate to it.
    """
    q0 = normalize(q0)
    q1 = normalize(q1)
    a = np.asarray(alpha, dtype=np.float64)
    scalar = a.ndim == 0
    a = np.atleast_1d(a)[:, None]
    dot = float(np.dot(q0, q1))
    if dot < 0.0:
        q1 = -q1
        dot = -dot
    dot = min(dot, 1.0)
    if dot > _SLERP_LINEAR_COS:
        out = normalize((1.0 - a) * q0 + a * q1)
    else:
        theta = np.arccos(dot)
        s = np.sin(theta)
        out = (np.sin((1.0 - a) * theta) / s) * q0 + (np.sin(a * theta) / s) * q1
        out = normalize(out)
    # Pin the endpoints bit-exactly: sin((1-a)θ)/sinθ is not exactly 1 in floating point.
    out = np.where(a == 0.0, q0, out)
    out = np.where(a == 1.0, q1, out)
    return out[0] if scalar else out


def angle_between(q0: np.ndarray, q1: np.ndarray) -> np.ndarray:
    """Rotation angle in radians between two orientations (sign-invariant)."""
    d = np.abs(np.sum(normalize(q0) * normalize(q1), axis=-1))
    return 2.0 * np.arccos(np.clip(d, 0.0, 1.0))
