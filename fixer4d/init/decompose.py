"""Decomposed initialization: one static cloud for the whole clip + time-local moving points.

    static   = MVS once on the per-view temporal median of the non-moving pixels, fused (Eq. 1-2)
               -> ONE cloud for every frame (Eq. 1-2 applied over time as well as views)
    dynamic  = per init frame, MVS only over the boxes of each view's moving-content regions (the
               other views' full frames as sources), kept where the mask says, fused -> the
               frame's moving points
    motion   = per moving point, 2D optical flow (OpenCV Farneback) chained over the neighbouring
               frames in every view where the point is visible, triangulated back to 3D (DLT):
               a short 3D track -> polynomial fits of degree 0..3 (smallest degree whose
               reprojection residual is within MOTION_FIT_TOL_PX), velocity / acceleration / jerk
               seeds and a local rigid fit (angular velocity) over the point's neighbours
    evidence = per static point, the colour spread across the train views (exposure-corrected):
               the view-dependent residual that decides the SH degree (fixer4d.model.effects)

Cost: the static plane sweep runs once for the clip; the per-frame sweeps cover only the moving
regions' boxes (15% of the demo's pixels, 34% of Panoptic's), so a clip costs about one
full-frame sweep plus the moving regions, instead of one full sweep per frame.

Output files in the init folder: ``decomposed.npz`` (``DecomposedInit.save``), ``masks.npz``
(fixer4d.init.masks format) and, for viewers and older readers, ``frame_XXXX.ply`` = the static
cloud plus that frame's moving points.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from fixer4d.atomic import atomic_path
from fixer4d.errors import InputError
from fixer4d.geometry.camera import Camera
from fixer4d.init.cloud import FrameCloud

DECOMPOSED_NAME = "decomposed.npz"

# ---- constants (each with its reason) ---------------------------------------------------------
# Margin (pixels at full resolution) added around each moving region before the plane sweep
# (fixer4d.init.mvs.roi_boxes): the reference windows need context around the object (fine
# level: ZNCC window 7 + aggregation 3 -> 4 px; coarse level at half resolution: window 3 +
# aggregation 3 -> 2 coarse = 4 px), plus room for the mask's own error. The sources are
# the full frames, so no margin is needed for disparity.
CROP_MARGIN_PX = 8
# A view whose moving mask has fewer pixels than this has no moving content worth a sweep
# (B1's mask cleanup already drops regions under ~0.05% of the image; 16 px is a 4x4 blob).
MIN_MOVING_PIXELS = 16
# Relative depth agreement for "the point is visible in this view" (same as the fusion test's
# order of magnitude, a little looser because crops are swept with fewer planes' support).
VISIBILITY_DEPTH_TOL = 0.02
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
# Blur (pixels) of the median images before the static points' colours are compared across
# views: sub-pixel misregistration of fine texture otherwise looks like view dependence (on the
# matte demo room, 4.3% of the points differ by > 0.06 unblurred, 0.9% after a 2 px blur,
# while a highlight, smooth over many pixels, survives it).
EVIDENCE_BLUR_SIGMA = 2.0
# Ridge (world units^2 x neighbours) of the rigid fit's normal equations, relative to the
# neighbourhood's squared radius: keeps collinear neighbourhoods from giving huge rotations.
ROTATION_RIDGE_REL = 1e-3


@dataclass
class DecomposedInit:
    """The decomposed init of a clip (shapes: N static, M moving points).

    frames: (F,) init frame indices; times: (F,) their clip times.
    static_points/colors: (N,3) float32 world / RGB [0,1]. static_view_std: (N,) float32
      exposure-corrected colour std across the train views that see the point (NaN: < 2 views).
    dyn_points/colors: (M,3); dyn_times: (M,) clip time of the point's frame; dyn_frames: (M,).
    dyn_coeffs: (M, 3, 3) float32 motion coefficients m1, m2, m3 (world units per clip time^k)
      of the point's selected polynomial (zeros above its degree).
    dyn_degree: (M,) int8 selected degree 0..3; -1 = no track (seen in < 2 views).
    dyn_fit_px: (M,) float32 RMS reprojection residual of the selected fit (NaN without track).
    dyn_omega: (M,3) float32 angular velocity (rad per clip time) of the local rigid fit;
      dyn_rot_gain: (M,) share of the neighbours' relative motion that rotation explains.
    scene_scale: median viewing distance (world units). info: statistics for the report.
    """

    frames: np.ndarray
    times: np.ndarray
    static_points: np.ndarray
    static_colors: np.ndarray
    static_view_std: np.ndarray
    dyn_points: np.ndarray
    dyn_colors: np.ndarray
    dyn_times: np.ndarray
    dyn_frames: np.ndarray
    dyn_coeffs: np.ndarray
    dyn_degree: np.ndarray
    dyn_fit_px: np.ndarray
    dyn_omega: np.ndarray
    dyn_rot_gain: np.ndarray
    scene_scale: float
    info: dict[str, Any] = field(default_factory=dict)

    @property
    def num_static(self) -> int:
        return int(self.static_points.shape[0])

    @property
    def num_dynamic(self) -> int:
        return int(self.dyn_points.shape[0])

    def frame_clouds(self) -> list[FrameCloud]:
        """Per init frame: the static cloud plus that frame's moving points (viewers, old readers)."""
        out = []
        for f, t in zip(self.frames.tolist(), self.times.tolist()):
            sel = self.dyn_frames == f
            out.append(FrameCloud(int(f), float(t), np.concatenate([self.static_points, self.dyn_points[sel]]),
                                  np.concatenate([self.static_colors, self.dyn_colors[sel]])))
        return out

    def save(self, out_dir: str | Path) -> Path:
        """Write ``out_dir/decomposed.npz`` atomically."""
        import json

        path = Path(out_dir) / DECOMPOSED_NAME
        path.parent.mkdir(parents=True, exist_ok=True)
        arrays = {k: np.asarray(getattr(self, k)) for k in _ARRAYS}
        with atomic_path(path) as tmp:
            with open(tmp, "wb") as fh:
                np.savez_compressed(fh, **arrays, scene_scale=np.float64(self.scene_scale),
                                    info=np.asarray(json.dumps(self.info)))
        return path

    @classmethod
    def load(cls, out_dir: str | Path) -> "DecomposedInit":
        """Read ``out_dir/decomposed.npz`` (InputError naming the file when absent or corrupt)."""
        import json

        path = Path(out_dir) / DECOMPOSED_NAME
        if not path.is_file():
            raise InputError(f"{path}: no decomposed init; rerun `fixer4d init` with decomposition on")
        try:
            with np.load(path, allow_pickle=False) as z:
                kw = {k: z[k] for k in _ARRAYS}
                return cls(**kw, scene_scale=float(z["scene_scale"]), info=json.loads(str(z["info"])))
        except (KeyError, ValueError, OSError) as exc:
            raise InputError(f"{path}: not a decomposed init ({exc}); delete the init folder and rerun") from None


_ARRAYS = ("frames", "times", "static_points", "static_colors", "static_view_std", "dyn_points", "dyn_colors",
           "dyn_times", "dyn_frames", "dyn_coeffs", "dyn_degree", "dyn_fit_px", "dyn_omega", "dyn_rot_gain")


def has_decomposed(out_dir: str | Path) -> bool:
    return (Path(out_dir) / DECOMPOSED_NAME).is_file()


# ---- helpers ------------------------------------------------------------------------------------
def static_median(images: np.ndarray, moving: np.ndarray) -> np.ndarray:
    """Per-pixel temporal median over the frames where the pixel does not move.

    images: (F, H, W, 3) float32; moving: (F, H, W) bool. A pixel that moves in every frame
    falls back to the plain median. Returns (H, W, 3) float32.
    """
    from fixer4d.init.masks import _median_without

    exclude = np.array(moving, bool)
    exclude[:, exclude.all(0)] = False  # moving in every frame: the plain median
    return _median_without(np.asarray(images, np.float32), exclude).astype(np.float32)


def _resize_mask(mask: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    if mask.shape == shape:
        return mask
    import cv2

    return cv2.resize(mask.astype(np.uint8), (shape[1], shape[0]), interpolation=cv2.INTER_NEAREST) > 0


def visible_in(points: np.ndarray, depth: np.ndarray, valid: np.ndarray, cam: Camera,
               tol: float = VISIBILITY_DEPTH_TOL) -> tuple[np.ndarray, np.ndarray]:
    """Which points (N,3) a depth map of ``cam`` sees: (visible (N,) bool, uv (N,2) pixels)."""
    uv, z = cam.project(points)
    with np.errstate(invalid="ignore"):
        iu, iv = np.floor(uv[:, 0]), np.floor(uv[:, 1])
        inside = (z > 0) & (iu >= 0) & (iu < cam.width) & (iv >= 0) & (iv < cam.height)
    d = np.zeros(points.shape[0])
    ok = np.zeros(points.shape[0], bool)
    ii, jj = iv[inside].astype(np.int64), iu[inside].astype(np.int64)
    d[inside] = depth[ii, jj]
    ok[inside] = valid[ii, jj]
    with np.errstate(invalid="ignore", divide="ignore"):
        vis = inside & ok & (d > 0) & (np.abs(z - d) <= tol * np.maximum(d, 1e-12))
    return vis, uv


def _bilinear(field2: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Sample an (H, W, C) field at continuous pixel coordinates uv (N, 2) (pixel centres at +0.5)."""
    h, w = field2.shape[:2]
    x = np.clip(uv[:, 0] - 0.5, 0, w - 1.001)
    y = np.clip(uv[:, 1] - 0.5, 0, h - 1.001)
    x0, y0 = np.floor(x).astype(np.int64), np.floor(y).astype(np.int64)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    return ((1 - fx) * (1 - fy) * field2[y0, x0] + fx * (1 - fy) * field2[y0, x0 + 1]
            + (1 - fx) * fy * field2[y0 + 1, x0] + fx * fy * field2[y0 + 1, x0 + 1])


def triangulate(uvs: np.ndarray, ok: np.ndarray, cams: Sequence[Camera]) -> tuple[np.ndarray, np.ndarray]:
    """Multi-view linear triangulation in normalized coordinates.

    Each observation gives the two DLT rows (x P3 - P1, y P3 - P2) . (X, 1) = 0; X is their
    least-squares solution (3x3 normal equations, solved in closed form for every point at once;
    a batched SVD of the homogeneous system was 10x slower for the same points).
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
                           k: int = ROTATION_NEIGHBOURS) -> np.ndarray:
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


class _FlowCache:
    """Farneback flow between adjacent video frames of one train view, computed on demand."""

    def __init__(self, load: Callable[[int, int], np.ndarray]) -> None:
        self._load = load
        self._gray: dict[tuple[int, int], np.ndarray] = {}
        self._flow: dict[tuple[int, int, int], np.ndarray] = {}
        self.count = 0

    def gray(self, v: int, f: int) -> np.ndarray:
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
        import cv2

        return cv2.calcOpticalFlowFarneback(self.gray(v, f), self.gray(v, g), None, FLOW_PYR_SCALE, FLOW_LEVELS,
                                            FLOW_WINSIZE, FLOW_ITERS, FLOW_POLY_N, FLOW_POLY_SIGMA, 0)

    def flow(self, v: int, f: int, g: int) -> np.ndarray:
        import cv2

        key = (v, f, g)
        if key not in self._flow:
            self._flow[key] = self._compute(v, f, g)
            self.count += 1
        return self._flow[key]


def seed_motion(points: np.ndarray, frame: int, num_frames: int, cams: Sequence[Camera],
                visible: np.ndarray, flows: _FlowCache, time_of: Callable[[int], float],
                moving_at: Callable[[int, int], np.ndarray | None] | None = None
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
                    uv[alive] = uv[alive] + _bilinear(flows.flow(v, g, h), uv[alive])
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


def view_color_spread(points: np.ndarray, images: Sequence[np.ndarray], results,
                      moving_any: Sequence[np.ndarray] | None = None) -> np.ndarray:
    """Exposure-corrected colour std (N,) of static points across the views that see them.

    images: V median images (any size; resized to each result's resolution); results: the V
    static DepthResults (visibility). Each view's colour offset from the across-view mean is
    removed first (its median over the points it sees), so a camera's exposure or white
    balance is not counted as view dependence. moving_any: optional V (H, W) bool at the images'
    resolution, pixels that move in some frame (their median colour mixes in moving content;
    they are left out). NaN where fewer than 2 views see the point.
    """
    import cv2

    V, N = len(results), points.shape[0]
    cols = np.zeros((V, N, 3))
    vis = np.zeros((V, N), bool)
    for v, r in enumerate(results):
        img = cv2.GaussianBlur(np.asarray(images[v], np.float32), (0, 0), EVIDENCE_BLUR_SIGMA)
        if img.shape[:2] != r.depth.shape:
            img = cv2.resize(img, (r.depth.shape[1], r.depth.shape[0]), interpolation=cv2.INTER_AREA)
        valid = r.valid if moving_any is None else r.valid & ~_resize_mask(np.asarray(moving_any[v]), r.depth.shape)
        vis[v], uv = visible_in(points, r.depth, valid, r.camera)
        cols[v, vis[v]] = _bilinear(img, uv[vis[v]])
    n = vis.sum(0)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = (cols * vis[..., None]).sum(0) / n[:, None]
        for v in range(V):
            m = vis[v] & (n >= 2)
            if m.any():
                cols[v] -= np.median(cols[v, m] - mean[m], axis=0)
        mean = (cols * vis[..., None]).sum(0) / n[:, None]
        var = (((cols - mean[None]) ** 2) * vis[..., None]).sum(0) / n[:, None]
    std = np.sqrt(var.mean(1))
    std[n < 2] = np.nan
    return std.astype(np.float32)


# ---- the decomposition ----------------------------------------------------------------------------
def decompose(scene, cams: Sequence[Camera], frames: Sequence[int], estimator, ranges, fusion_config,
              masks: np.ndarray, timer=None) -> tuple[DecomposedInit, list]:
    """Static cloud once + per-frame moving points with seeded motion (module docstring).

    Returns (the DecomposedInit, the static sweep's V DepthResults).

    scene: the MultiViewVideo (train views only are read); cams: the V posed train cameras;
    frames: init frame indices (F); estimator: a DepthEstimator; ranges: per-view (near, far);
    fusion_config: FusionConfig; masks: (V, F, H, W) bool moving-content masks of those frames.
    timer: optional object with ``add(stage, t0)`` (fixer4d.init.report.Timer).
    """
    import time

    from fixer4d.init.fusion import fuse_depths, fuse_results, scene_scale

    def tick(stage: str, t0: float) -> None:
        if timer is not None:
            timer.add(stage, t0)

    frames = [int(f) for f in frames]
    V, F = len(cams), len(frames)
    if masks.shape[:2] != (V, F):
        raise InputError(f"decompose: masks are {masks.shape[:2]}, expected ({V} views, {F} frames)")
    t0 = time.perf_counter()
    imgs = np.stack([[np.asarray(scene.frame(f, c), np.float32) for c in scene.train_ids] for f in frames])  # F,V
    tick("load", t0)

    # -- static: one sweep on the median of the non-moving pixels ---------------------------------
    t0 = time.perf_counter()
    medians = [static_median(imgs[:, v], masks[v]) for v in range(V)]
    tick("static_median", t0)
    t0 = time.perf_counter()
    static_res = estimator.estimate(medians, list(cams), ranges)
    tick("mvs", t0)
    t0 = time.perf_counter()
    s_pts, s_cols = fuse_results(medians, static_res, fusion_config)
    tick("fusion", t0)
    scale = scene_scale(s_pts, cams) if len(s_pts) else 1.0

    # -- dynamic: per frame, sweeps on the moving regions only ---------------------------------------
    from fixer4d.init.mvs import PlaneSweepMVS, roi_boxes

    d_pts, d_cols, d_frames, d_vis, per_frame = [], [], [], [], []
    crop_pixels = 0
    for j, f in enumerate(frames):
        t0 = time.perf_counter()
        rois = [masks[v, j] if masks[v, j].sum() >= MIN_MOVING_PIXELS else None for v in range(V)]
        use = [v for v in range(V) if rois[v] is not None]
        pts = np.zeros((0, 3), np.float32)
        cols = np.zeros((0, 3), np.float32)
        vis = np.zeros((V, 0), bool)
        if len(use) >= 2:
            crop_pixels += sum((x1 - x0) * (y1 - y0) for v in use for x0, y0, x1, y1 in roi_boxes(rois[v], CROP_MARGIN_PX))
            if isinstance(estimator, PlaneSweepMVS):  # sweeps only the regions, the full frames as sources
                res = estimator.estimate(list(imgs[j]), list(cams), ranges, rois=rois, roi_margin=CROP_MARGIN_PX)
            else:
                res = estimator.estimate(list(imgs[j]), list(cams), ranges)
            tick("mvs", t0)
            t0 = time.perf_counter()
            valids = [r.valid & _resize_mask(masks[v, j], r.depth.shape) if rois[v] is not None
                      else np.zeros(r.depth.shape, bool) for v, r in enumerate(res)]
            if sum(int(v.sum()) for v in valids) > 0:
                import cv2

                rimgs = [im if im.shape[:2] == r.depth.shape else
                         cv2.resize(im, (r.depth.shape[1], r.depth.shape[0]), interpolation=cv2.INTER_AREA)
                         for im, r in zip(imgs[j], res)]
                pts, cols = fuse_depths(rimgs, [r.depth for r in res], [r.camera for r in res], valids, fusion_config)
            vis = np.zeros((V, len(pts)), bool)
            for v, r in enumerate(res):
                vis[v], _ = visible_in(pts, r.depth, valids[v], r.camera)
            tick("fusion", t0)
        else:
            tick("mvs", t0)
        d_pts.append(pts)
        d_cols.append(cols)
        d_frames.append(np.full(len(pts), f, np.int64))
        d_vis.append(vis)
        per_frame.append({"frame": f, "moving_views": len(use), "moving_points": int(len(pts))})

    # -- motion seeds: chained flow, triangulated, fitted ---------------------------------------------
    flows = _FlowCache(lambda f, v: np.asarray(scene.frame(f, scene.train_ids[v]), np.float32))
    t0 = time.perf_counter()  # decoding the neighbouring frames is loading, not preparation
    for f in sorted({g for f in frames for g in range(f - TRACK_HALF_FRAMES, f + TRACK_HALF_FRAMES + 1)
                     if 0 <= g < scene.num_frames}):
        for v in range(V):
            flows.gray(v, f)
    tick("load", t0)
    t0 = time.perf_counter()
    # the flows of every chain that starts from visible moving points, in parallel
    flows.prefetch([(v, f + d * (s - 1), f + d * s) for j, f in enumerate(frames) for v in range(V)
                    if d_vis[j].shape[1] and d_vis[j][v].any()
                    for d in (1, -1) for s in range(1, TRACK_HALF_FRAMES + 1) if 0 <= f + d * s < scene.num_frames])
    coeffs_l, deg_l, rms_l = [], [], []
    for j, f in enumerate(frames):
        if len(d_pts[j]) == 0:
            coeffs_l.append(np.zeros((0, 4, 3)))
            deg_l.append(np.zeros(0, np.int8))
            rms_l.append(np.zeros(0))
            continue
        c, d, r = seed_motion(d_pts[j].astype(np.float64), f, scene.num_frames, cams, d_vis[j], flows, scene.time)
        coeffs_l.append(c)
        deg_l.append(d)
        rms_l.append(r)
    dyn_points = np.concatenate(d_pts).astype(np.float32) if d_pts else np.zeros((0, 3), np.float32)
    dyn_frames = np.concatenate(d_frames) if d_frames else np.zeros(0, np.int64)
    coeffs = np.concatenate(coeffs_l) if coeffs_l else np.zeros((0, 4, 3))
    degree = np.concatenate(deg_l) if deg_l else np.zeros(0, np.int8)
    rms = np.concatenate(rms_l) if rms_l else np.zeros(0)
    omega, rot_gain = local_angular_velocity(dyn_points.astype(np.float64), coeffs[:, 1], degree >= 1, dyn_frames)
    tick("motion", t0)

    # -- evidence for the SH degree ---------------------------------------------------------------------
    t0 = time.perf_counter()
    view_std = view_color_spread(s_pts.astype(np.float64), medians, static_res, masks.any(axis=1)) if len(s_pts) else np.zeros(0, np.float32)
    tick("evidence", t0)

    full_pixels = sum(c.width * c.height for c in cams)
    info = {"static_points": int(len(s_pts)), "moving_points": int(len(dyn_points)),
            "moving_pixel_share": float(masks.mean()), "crop_pixel_share": float(crop_pixels / max(full_pixels * F, 1)),
            "flow_fields": flows.count, "per_frame": per_frame,
            "tracked_share": float((degree >= 0).mean()) if len(degree) else None}
    return DecomposedInit(
        frames=np.asarray(frames, np.int64), times=np.asarray([scene.time(f) for f in frames], np.float64),
        static_points=s_pts.astype(np.float32), static_colors=s_cols.astype(np.float32), static_view_std=view_std,
        dyn_points=dyn_points,
        dyn_colors=(np.concatenate(d_cols) if d_cols else np.zeros((0, 3))).astype(np.float32),
        dyn_times=np.asarray([scene.time(int(f)) for f in dyn_frames], np.float64),
        dyn_frames=dyn_frames, dyn_coeffs=coeffs[:, 1:].astype(np.float32), dyn_degree=degree.astype(np.int8),
        dyn_fit_px=rms.astype(np.float32), dyn_omega=omega.astype(np.float32), dyn_rot_gain=rot_gain.astype(np.float32), scene_scale=float(scale), info=info), static_res


def run_decomposed(scene, cams: Sequence[Camera], frames: list[int], estimator, ranges, config, out_dir: Path,
                   report: dict[str, Any], timer, t_start: float, want_quality: bool, progress: bool
                   ) -> tuple[list[FrameCloud], dict[str, Any]]:
    """``run_init``'s MVS path with decomposition: masks -> ``decompose`` -> files + report.

    Writes ``masks.npz``, ``decomposed.npz``, ``frame_XXXX.ply`` (static + that frame's moving
    points) and ``init_report.json`` (with a ``decomposition`` section). Returns (the per-frame
    clouds, report) like ``run_init``.
    """
    import time

    from fixer4d.init import quality as Q
    from fixer4d.init.cloud import save_frame_clouds
    from fixer4d.init.constants import QUALITY_COMPLETENESS_REL
    from fixer4d.init.masks import MASKS_NAME, moving_masks_for_scene, save_masks
    from fixer4d.init.report import finish_report, gt_depth_at

    out_dir = Path(out_dir)
    from fixer4d.init.masks import statistics_frames

    t0 = time.perf_counter()  # decode the frames the masks' statistics read (loading, not preparation)
    for f in statistics_frames(scene.num_frames, frames):
        for c in scene.train_ids:
            scene.frame(f, c)
    timer.add("load", t0)
    t0 = time.perf_counter()
    masks = moving_masks_for_scene(scene, scene.train_ids, frames)
    timer.add("masks", t0)
    if progress:
        print(f"[init] decomposed MVS: {len(frames)} frames, moving pixels {100 * masks.mean():.1f}%", flush=True)
    dec, static_res = decompose(scene, cams, frames, estimator, ranges, config.fusion, masks, timer)
    t0 = time.perf_counter()
    out_dir.mkdir(parents=True, exist_ok=True)
    save_masks(out_dir / MASKS_NAME, masks, [scene.cameras[i].name for i in scene.train_ids], frames)
    dec.save(out_dir)
    clouds = dec.frame_clouds()
    save_frame_clouds(out_dir, clouds)
    timer.add("write", t0)

    per_frame = [dict(p) for p in dec.info["per_frame"]]
    for p, c in zip(per_frame, clouds):
        p["points"] = len(c)
    if want_quality:
        t0 = time.perf_counter()
        all_ids = list(scene.train_ids) + [i for i in scene.test_ids if i not in scene.train_ids]
        for p, c in zip(per_frame, clouds):
            f = c.frame
            surface, sc = Q.surface_samples([scene.depth(f, i) for i in all_ids], [scene.cameras[i] for i in all_ids])
            p.update(Q.cloud_quality(c.points, surface, sc))
        acc = [p["accuracy"] for p in per_frame if p.get("accuracy") is not None]
        quality = {"accuracy": float(np.mean(acc)) if acc else None,
                   "accuracy_rel": float(np.mean([p["accuracy_rel"] for p in per_frame
                                                  if p.get("accuracy_rel") is not None])) if acc else None,
                   "completeness": float(np.mean([p["completeness"] for p in per_frame])),
                   "completeness_tolerance_rel": QUALITY_COMPLETENESS_REL, "depth_abs_rel": None}
        # the static sweep against the middle init frame's true depth, moving pixels excluded
        j = len(frames) // 2
        st = [Q.depth_quality(r.depth, r.valid & ~_resize_mask(masks[v, j], r.depth.shape),
                              np.where(_resize_mask(masks[v, j], r.depth.shape), np.nan,
                                       gt_depth_at(scene, i, frames[j], r.camera)))
              for v, (r, i) in enumerate(zip(static_res, scene.train_ids))]
        quality.update(Q.summarize_depth(st))
        report["quality"] = quality
        timer.add("quality", t0)
    report["points_per_frame"] = [len(c) for c in clouds]
    report["per_frame"] = per_frame
    report["decomposition"] = {k: v for k, v in dec.info.items() if k != "per_frame"}
    finish_report(report, timer, t_start, config, estimator, out_dir)
    return clouds, report
