"""Exact ray/primitive geometry of the synthetic scenes' ray-caster (fixer4d/scene/raycast.py).

Each primitive lives in its own local frame: plane, sphere, oriented box (slabs) and capped
cylinder. ``intersect_local`` gives the nearest hit of rays from a common origin,
``surface_local`` the outward normal and texture coordinates at a surface point.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# Hits closer than this ray parameter are ignored (the ray origin sits on no surface; this only
# guards against a hit at t = 0 from rounding).
T_MIN = 1e-9


@dataclass(frozen=True)
class Shape:
    """Canonical geometry in the object's local frame.

    plane: z = 0, normal +z, optionally bounded to |x| <= half[0], |y| <= half[1]
    (``half`` None = infinite). sphere: centred, ``radius``. box: centred, half extents
    ``half`` (3,). cylinder: axis local y, ``radius``, |y| <= half[1] (capped).
    """

    kind: str
    radius: float = 0.0
    half: np.ndarray | None = None

    @property
    def bound_radius(self) -> float | None:
        """Radius of a local-origin sphere enclosing the shape (None: unbounded plane)."""
        if self.kind == "sphere":
            return self.radius
        if self.kind == "cylinder":
            return float(np.hypot(self.radius, self.half[1]))
        if self.half is None:
            return None
        return float(np.linalg.norm(self.half))


def intersect_local(shape: Shape, o: np.ndarray, d: np.ndarray) -> np.ndarray:
    """Nearest hit parameter t > T_MIN (N,) of rays o + t d (local frame), inf on a miss.

    o: (3,) the common origin (a pinhole camera's rays share it); d: (N, 3) directions.
    """
    n = d.shape[0]
    inf = np.full(n, np.inf)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        if shape.kind == "plane":
            t = -o[2] / d[:, 2]
            ok = np.isfinite(t) & (t > T_MIN)
            if shape.half is not None:
                p = o + t[:, None] * d
                ok &= (np.abs(p[:, 0]) <= shape.half[0]) & (np.abs(p[:, 1]) <= shape.half[1])
            return np.where(ok, t, inf)
        if shape.kind == "sphere":
            a = np.einsum("ij,ij->i", d, d)
            b = d @ o
            c = float(o @ o) - shape.radius ** 2
            disc = b * b - a * c
            sq = np.sqrt(np.maximum(disc, 0.0))
            t0 = (-b - sq) / a
            t1 = (-b + sq) / a
            t = np.where(t0 > T_MIN, t0, t1)
            return np.where((disc >= 0) & (t > T_MIN), t, inf)
        if shape.kind == "box":
            inv = 1.0 / d
            ta = (-shape.half - o) * inv
            tb = (shape.half - o) * inv
            lo = np.minimum(ta, tb)
            hi = np.maximum(ta, tb)
            # fmax/fmin skip the NaN of 0 * inf (a ray parallel to a slab, starting on it).
            tnear = np.fmax(np.fmax(lo[:, 0], lo[:, 1]), lo[:, 2])
            tfar = np.fmin(np.fmin(hi[:, 0], hi[:, 1]), hi[:, 2])
            t = np.where(tnear > T_MIN, tnear, tfar)
            return np.where((tfar >= tnear) & (t > T_MIN), t, inf)
        if shape.kind == "cylinder":
            r, h = shape.radius, shape.half[1]
            a = d[:, 0] ** 2 + d[:, 2] ** 2
            b = o[0] * d[:, 0] + o[2] * d[:, 2]
            c = o[0] ** 2 + o[2] ** 2 - r * r
            disc = b * b - a * c
            sq = np.sqrt(np.maximum(disc, 0.0))
            best = inf.copy()
            for root in ((-b - sq) / a, (-b + sq) / a):
                y = o[1] + root * d[:, 1]
                ok = (disc >= 0) & (a > 0) & (root > T_MIN) & (np.abs(y) <= h)
                best = np.where(ok & (root < best), root, best)
            for cap in (-h, h):
                tc = (cap - o[1]) / d[:, 1]
                px = o[0] + tc * d[:, 0]
                pz = o[2] + tc * d[:, 2]
                ok = np.isfinite(tc) & (tc > T_MIN) & (px * px + pz * pz <= r * r)
                best = np.where(ok & (tc < best), tc, best)
            return best
    raise ValueError(f"unknown shape kind {shape.kind!r}")


def surface_local(shape: Shape, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Outward unit normals (N, 3) and texture coordinates (N, 3) at local surface points p.

    Flat faces zero the coordinate along their normal so a face never sits on a texture cell
    boundary (which would flicker between cells from rounding).
    """
    tc = p.copy()
    if shape.kind == "plane":
        nrm = np.zeros_like(p)
        nrm[:, 2] = 1.0
        tc[:, 2] = 0.0
        return nrm, tc
    if shape.kind == "sphere":
        return p / np.linalg.norm(p, axis=1, keepdims=True), tc
    if shape.kind == "box":
        axis = np.argmax(np.abs(p) / shape.half, axis=1)
        nrm = np.zeros_like(p)
        rows = np.arange(p.shape[0])
        nrm[rows, axis] = np.sign(p[rows, axis])
        tc[rows, axis] = 0.0
        return nrm, tc
    if shape.kind == "cylinder":
        radial = np.hypot(p[:, 0], p[:, 2])
        cap = np.abs(np.abs(p[:, 1]) - shape.half[1]) < np.abs(radial - shape.radius)
        nrm = np.zeros_like(p)
        side_scale = 1.0 / np.maximum(radial, 1e-12)
        nrm[:, 0] = np.where(cap, 0.0, p[:, 0] * side_scale)
        nrm[:, 2] = np.where(cap, 0.0, p[:, 2] * side_scale)
        nrm[:, 1] = np.where(cap, np.sign(p[:, 1]), 0.0)
        tc[:, 1] = np.where(cap, 0.0, tc[:, 1])
        return nrm, tc
    raise ValueError(f"unknown shape kind {shape.kind!r}")
