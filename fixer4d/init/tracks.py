"""Motion seeds of moving points: short 3D tracks from 2D optical flow chained over the
neighbouring frames in every view where a point is visible (OpenCV Farneback, ``FlowCache``),
triangulated back to 3D (DLT, ``triangulate``), fitted by the smallest polynomial degree 0..3
that explains them (``fit_tracks``), and the angular velocity of a local rigid fit over each
point's neighbours (``local_angular_velocity``). ``seed_motion`` runs the chain for one frame."""
from __future__ import annotations

from typing import Callable, Sequence

import numpy as np

from fixer4d.geometry.camera import Camera
from fixer4d.init.view_sampling import bilinear

# ---- constants (each with its reason) ---------------------------------------------------------
# Frames chained on each side of an init frame for a motion track: 3 frames give 7 samples,
# enough to tell degree 0..3 apart with residual to spare, and flow chained further drifts.
TRACK_HALF_FRAMES = 3
# A track sample needs the point in at least this many views to be triangulated.
TRACK_MIN_VIEWS = 2
# Degree selection: the smallest polynomial degree whose RMS reprojection residual over the
# track is within this many pixels (optical-flow end-point error on textured content is
# ~0.3-1 px; 1 px keeps flow noise from buying extra degrees).
MOTION_FIT_TOL_PX = 1.0
# Farneback parameters (OpenCV tutorial values; levels 4 so that ~16 px motions are caught at
# the coarsest level of a 200x150 image). OpenCV's DIS flow (medium preset) is 1.8x faster and
# fits the demo's tracks better, but loses the fast_thin spec's spinning blades (every track
# degree 0, no rotation: tests/init/test_decompose.py), so Farneback stays.
FLOW_PYR_SCALE, FLOW_LEVELS, FLOW_WINSIZE, FLOW_ITERS, FLOW_POLY_N, FLOW_POLY_SIGMA = 0.5, 4, 15, 3, 5, 1.2
# Neighbours of a moving point (same frame) in the local rigid fit of its angular velocity:
# 16 neighbours over-determine the 3 unknowns and average flow noise, and still stay on one
# object at the demo's density (a 0.3-unit cube carries hundreds of points).
ROTATION_NEIGHBOURS = 16
# Ridge (world units^2 x neighbours) of the rigid fit's normal equations, relative to the
# neighbourhood's squared radius: keeps collinear neighbourhoods from giving huge rotations.
ROTATION_RIDGE_REL = 1e-3


def triangulate(uvs: np.ndarray, ok: np.ndarray, cams: Sequence[Camera]) -> tuple[np.ndarray, np.ndarray]:
    """Multi-view linear triangulation in normalized coordinates.

    Each observation gives the two DLT rows (x P3 - P1, y P3 - P2) . (X, 1) = 0; X is their
    least-squares solution (3x3 normal equations, solved in closed form for every point at once;
    a batched SVD of the homogeneous system is 10x slower for the same points).
    uvs: (V, N, 2) pixels; ok: (V, N) which observations to use. Returns (X (N,3) float64,
    good (N,) bool: >= TRACK_MIN_VIEWS observations, a well-conditioned system and in front of
    every used camera).
    """
    V, N = ok.shape
    M = np.zeros((N, 3, 3))
    rhs = np.zeros((N, 3))
    for v, cam in enumerate(cams):
        P = cam.w2c[:3, :4]
        uv1 = np.concatenate([np.nan_to_num(uvs[v]), np.ones((N, 1))], 1) @ np.linalg.inv(cam.K).T
        w = ok[v].astype(np.float64)[:, None]
        for row in (uv1[:, 0:1] * P[2] - P[0], uv1[:, 1:2] * P[2] - P[1]):
            a = w * row[:, :3]
            M += a[:, :, None] * a[:, None, :]
            rhs -= a * (w * row[:, 3:4])
    good = ok.sum(0) >= TRACK_MIN_VIEWS
    # closed-form inverse through the adjugate; a near-singular system (parallel rays) is not good
    adj = np.stack([np.cross(M[:, 1], M[:, 2]), np.cross(M[:, 2], M[:, 0]), np.cross(M[:, 0], M[:, 1])], 2)
    det = np.einsum("ni,ni->n", M[:, 0], adj[:, :, 0])
    scale = np.einsum("nii->n", M) ** 3
    good &= np.abs(det) > 1e-12 * np.maximum(scale, 1e-300)
    X = np.full((N, 3), np.nan)
    with np.errstate(divide="ignore", invalid="ignore"):
        X[good] = np.einsum("nij,nj->ni", adj[good], rhs[good]) / det[good, None]
    for v, cam in enumerate(cams):
        z = cam.world_to_camera(np.nan_to_num(X))[:, 2]
        good &= ~ok[v] | (z > 0)
    good &= np.all(np.isfinite(X), 1)
    return X, good


def fit_tracks(dts: np.ndarray, X: np.ndarray, ok: np.ndarray, obs: np.ndarray, obs_ok: np.ndarray,
               cams: Sequence[Camera], tol_px: float = MOTION_FIT_TOL_PX
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Smallest-degree polynomial fit of each track.

    dts: (S,) clip-time offsets of the samples (0 = the point's own frame); X: (S, N, 3)
    triangulated positions; ok: (S, N) usable samples; obs: (S, V, N, 2) the 2D observations
    and obs_ok (S, V, N) which exist. A degree d is judged only with >= d + 2 samples (one more
    than it can interpolate); it is chosen when the RMS reprojection error of the fitted track
    over every observation is <= ``tol_px``. Returns (coeffs (N, 4, 3) c0..c3, degree (N,) int8
    (-1 = fewer than 2 samples), rms_px (N,)).
    """
    S, N = ok.shape
    coeffs = np.zeros((N, 4, 3))
    degree = np.full(N, -1, np.int8)
    rms = np.full(N, np.nan)
    n_ok = ok.sum(0)
    W = ok.astype(np.float64)  # (S, N)
    Xz = np.nan_to_num(X)
    for d in range(4):
        todo = (degree < 0) & (n_ok >= d + 2)
        if not todo.any():
            continue
        B = np.stack([dts ** k for k in range(d + 1)], 1)  # (S, d+1)
        idx = np.nonzero(todo)[0]
        w = W[:, idx]  # (S, n)
        M = np.einsum("sn,sk,sl->nkl", w, B, B) + 1e-12 * np.eye(d + 1)
        b = np.einsum("sn,sk,snc->nkc", w, B, Xz[:, idx])
        c = np.linalg.solve(M, b)  # (n, d+1, 3)
        fit = np.einsum("sk,nkc->snc", B, c)  # (S, n, 3)
        err2 = np.zeros(idx.size)
        cnt = np.zeros(idx.size)
        for v, cam in enumerate(cams):
            m = obs_ok[:, v, idx] & ok[:, idx]  # (S, n)
            # one projection per sample: (n, 3) @ (3, 3) stays under OpenBLAS's threading size
            # (~65k rows), whose threads cost 40 ms per product on the shared 2-core machine
            uv = np.stack([cam.project(fit[j])[0] for j in range(S)])
            with np.errstate(over="ignore", invalid="ignore"):
                e = np.sum((np.nan_to_num(uv, nan=1e6) - obs[:, v, idx]) ** 2, -1)
            err2 += np.where(m, np.minimum(e, 1e6), 0.0).sum(0)
            cnt += m.sum(0)
        r = np.sqrt(err2 / np.maximum(cnt, 1))
        accept = (r <= tol_px) | (d == 3) | (n_ok[idx] < d + 3)
        # the last degree the samples can judge is accepted even when above tolerance (best effort)
        sel = idx[accept]
        degree[sel] = d
        rms[sel] = r[accept]
        coeffs[sel, : d + 1] = c[accept]
    return coeffs, degree, rms


def local_angular_velocity(points: np.ndarray, vel: np.ndarray, tracked: np.ndarray, groups: np.ndarray,
                           k: int = ROTATION_NEIGHBOURS) -> tuple[np.ndarray, np.ndarray]:
    """Angular velocity (N,3) of the rigid motion that best explains each tracked point's
    neighbours' velocities (same ``groups`` value, i.e. same frame): v_j - v_i = w x (x_j - x_i),
    and the share (N,) of the neighbours' relative-velocity energy that the rotation explains
    (1 - residual with w / residual without; 0 = pure translation). Untracked points or too few
    neighbours get 0 for both."""
    from scipy.spatial import cKDTree

    out = np.zeros((points.shape[0], 3))
    gain = np.zeros(points.shape[0])
    for g in np.unique(groups):
        sel = np.nonzero((groups == g) & tracked)[0]
        if sel.size < 4:
            continue
        kk = min(k, sel.size - 1)
        _, nb = cKDTree(points[sel]).query(points[sel], k=kk + 1)
        nb = sel[np.asarray(nb)[:, 1:]]  # (n, kk)
        r = points[nb] - points[sel][:, None]  # (n, kk, 3)
        dv = vel[nb] - vel[sel][:, None]
        # least squares on w x r = dv: normal matrix sum(|r|^2 I - r r^T), right side sum(r x dv)
        rr = np.einsum("nki,nki->n", r, r)
        M = rr[:, None, None] * np.eye(3) - np.einsum("nki,nkj->nij", r, r)
        M = M + ROTATION_RIDGE_REL * rr[:, None, None] * np.eye(3)
        b = np.cross(r, dv).sum(1)
        w = np.linalg.solve(M + 1e-18 * np.eye(3), b[..., None])[..., 0]
        res = dv - np.cross(w[:, None, :], r)
        res_rot = np.einsum("nki,nki->n", res, res)
        res_trans = np.einsum("nki,nki->n", dv, dv)
        out[sel] = w
        gain[sel] = np.where(res_trans > 0, 1.0 - res_rot / np.maximum(res_trans, 1e-30), 0.0)
    return out, gain


class FlowCache:
    """Farneback flow between adjacent video frames of one train view, computed on demand."""

    def __init__(self, load: Callable[[int, int], np.ndarray]) -> None:
        """load(frame, view) -> (H, W, 3) float RGB in [0, 1]. ``count``: flows computed."""
        self._load = load
        self._gray: dict[tuple[int, int], np.ndarray] = {}
        self._flow: dict[tuple[int, int, int], np.ndarray] = {}
        self.count = 0

    def gray(self, v: int, f: int) -> np.ndarray:
        """(H, W) uint8 gray of view v at frame f (loaded once)."""
        import cv2

        key = (v, f)
        if key not in self._gray:
            img = np.clip(self._load(f, v) * 255.0, 0, 255).astype(np.uint8)
            self._gray[key] = cv2.cvtColor(img, cv2.COLOR_RGB2GRAY)
        return self._gray[key]

    def prefetch(self, keys: Sequence[tuple[int, int, int]]) -> None:
        """Compute the flows (view, from, to) ``keys`` in parallel threads (OpenCV releases the
        GIL); the grays must be loaded already."""
        import os
        from concurrent.futures import ThreadPoolExecutor

        todo = sorted({k for k in keys if k not in self._flow})
        with ThreadPoolExecutor(max(1, min(len(todo), os.cpu_count() or 1))) as pool:
            for k, fl in zip(todo, pool.map(lambda k: self._compute(*k), todo)):
                self._flow[k] = fl
        self.count += len(todo)

    def _compute(self, v: int, f: int, g: int) -> np.ndarray:
        """(H, W, 2) Farneback flow of view v from frame f to frame g, pixels."""
        import cv2

        return cv2.calcOpticalFlowFarneback(self.gray(v, f), self.gray(v, g), None, FLOW_PYR_SCALE, FLOW_LEVELS,
                                            FLOW_WINSIZE, FLOW_ITERS, FLOW_POLY_N, FLOW_POLY_SIGMA, 0)

    def flow(self, v: int, f: int, g: int) -> np.ndarray:
        """(H, W, 2) flow of view v from frame f to frame g (computed once)."""
        key = (v, f, g)
        if key not in self._flow:
            self._flow[key] = self._compute(v, f, g)
            self.count += 1
        return self._flow[key]


def seed_motion(points: np.ndarray, frame: int, num_frames: int, cams: Sequence[Camera],
                visible: np.ndarray, flows: FlowCache, time_of: Callable[[int], float]
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Short 3D tracks of one frame's moving points by chained 2D flow, fitted (``fit_tracks``).

    points: (N,3) at ``frame``; cams: the V full-resolution train cameras; visible: (V, N) where
    each point is seen at ``frame``. Returns (coeffs (N,4,3), degree (N,), rms_px (N,)).
    """
    V, N = visible.shape
    offsets = [s for s in range(-TRACK_HALF_FRAMES, TRACK_HALF_FRAMES + 1) if 0 <= frame + s < num_frames]
    S = len(offsets)
    obs = np.zeros((S, V, N, 2))
    obs_ok = np.zeros((S, V, N), bool)
    t0 = time_of(frame)
    for v, cam in enumerate(cams):
        uv0, _ = cam.project(points)
        for direction in (1, -1):
            uv = uv0.copy()
            alive = visible[v].copy()
            g = frame
            for s in range(1, TRACK_HALF_FRAMES + 1):
                h = frame + direction * s
                if not 0 <= h < num_frames:
                    break
                if alive.any():
                    uv[alive] = uv[alive] + bilinear(flows.flow(v, g, h), uv[alive])
                    alive &= (uv[:, 0] >= 0) & (uv[:, 0] < cam.width) & (uv[:, 1] >= 0) & (uv[:, 1] < cam.height)
                j = offsets.index(direction * s)
                obs[j, v] = np.nan_to_num(uv)
                obs_ok[j, v] = alive
                g = h
        j0 = offsets.index(0)
        obs[j0, v] = np.nan_to_num(uv0)
        obs_ok[j0, v] = visible[v]
    X = np.full((S, N, 3), np.nan)
    ok = np.zeros((S, N), bool)
    for j, s in enumerate(offsets):
        if s == 0:
            X[j] = points
            ok[j] = visible.sum(0) >= TRACK_MIN_VIEWS
        else:
            X[j], ok[j] = triangulate(obs[j], obs_ok[j], cams)
    ok &= ok[offsets.index(0)][None]
    dts = np.array([time_of(frame + s) - t0 for s in offsets])
    return fit_tracks(dts, X, ok, obs, obs_ok, cams)
