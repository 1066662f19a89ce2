"""Multi-view depth for one timestamp: the DepthEstimator protocol and a plane-sweep stereo.

``PlaneSweepMVS`` (torch, CPU, deterministic), for every reference view:
  1. fronto-parallel planes uniform in inverse depth between the view's near and far bounds;
  2. every source view warped into the reference per plane through the plane-induced homography,
     evaluated at pixel centres (u + 0.5, v + 0.5) and sampled with ``grid_sample(align_corners=
     False)``, whose normalized coordinate x_n = 2 u / W - 1 puts pixel i's centre exactly at
     continuous u = i + 0.5, the convention of ``Camera``;
  3. ZNCC over a window (box filters) per source, averaged over the best k sources (robust to
     a source that is occluded at the pixel), then a box aggregation over the image plane;
  4. winner-take-all over planes with a parabola fit around the winner (sub-plane refinement in
     inverse depth), streamed over chunks of planes so memory stays bounded;
  5. confidence from the cost curve (peak ZNCC x normalized peak gap) and validity from texture,
     peak score, peak distinctiveness, range borders and a forward-backward geometric check
     between views.

``MVSAnywhereEstimator`` runs the real ``mvsanywhere`` package (Izquierdo et al., CVPR 2025) when
it is importable and local weights are given; otherwise it raises BackendUnavailable.
"""
from __future__ import annotations

import contextlib
import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Iterator, Protocol, Sequence, runtime_checkable

import numpy as np
import torch
import torch.nn.functional as F

from fixer4d.errors import BackendUnavailable, InputError
from fixer4d.geometry.camera import Camera, rig_extent
from fixer4d.geometry.rig import axes_converge, axes_system, common_view_bounds
from fixer4d.init import constants as C

MVSANYWHERE_WEIGHTS_ENV = "FIXER4D_MVSANYWHERE_WEIGHTS"
MVSANYWHERE_CONFIG_ENV = "FIXER4D_MVSANYWHERE_CONFIG"


@dataclass
class DepthResult:
    """Depth of one view at the estimator's working resolution.

    depth: (H, W) float32 z-depth (0 where invalid). valid: (H, W) bool. confidence: (H, W)
    float32 in [0, 1]. camera: the camera at that resolution (H, W may differ from the input
    image when the estimator works at a reduced scale).
    """

    depth: np.ndarray
    valid: np.ndarray
    confidence: np.ndarray
    camera: Camera


@runtime_checkable
class DepthEstimator(Protocol):
    """V synchronized images + cameras -> one DepthResult per view."""

    name: str

    def estimate(self, images: Sequence[np.ndarray], cameras: Sequence[Camera],
                 depth_ranges: Sequence[tuple[float, float]] | None = None) -> list[DepthResult]:
        """images: V (H, W, 3) float32 RGB in [0, 1]; cameras: V posed cameras; depth_ranges:
        optional per-view (near, far) z-depths."""
        ...


# ---- depth ranges ---------------------------------------------------------------------------
def depth_ranges_from_points(points: np.ndarray, cameras: Sequence[Camera]) -> list[tuple[float, float]] | None:
    """Per-view (near, far) from 3D points (e.g. SfM) seen in the view: percentiles of their
    depths widened by a margin. None when a view sees fewer than 10 points."""
    points = np.asarray(points, np.float64).reshape(-1, 3)
    out = []
    for cam in cameras:
        uv, z = cam.project(points)
        ok = (z > 0) & np.all(np.isfinite(uv), 1)
        ok &= (uv[:, 0] >= 0) & (uv[:, 0] < cam.width) & (uv[:, 1] >= 0) & (uv[:, 1] < cam.height)
        if ok.sum() < 10:
            return None
        lo, hi = np.percentile(z[ok], C.MVS_POINTS_PERCENTILES)
        out.append((float(lo / C.MVS_POINTS_MARGIN), float(hi * C.MVS_POINTS_MARGIN)))
    return out


def depth_ranges_from_rig(cameras: Sequence[Camera]) -> list[tuple[float, float]] | None:
    """Per-view (near, far): the z-range of the cameras' common view (frustum overlap) in each
    view; None when the frusta share no view."""
    try:
        vb = common_view_bounds(cameras)
    except InputError:
        return None
    return [(float(a), float(b)) for a, b in vb.depth_ranges]


def scene_depth_ranges(cameras: Sequence[Camera], sfm_points: np.ndarray | None = None
                       ) -> tuple[list[tuple[float, float]], str]:
    """The plane sweep's per-view depth ranges from the capture's own cues, and their source:
    sparse SfM points when given (and seen by every view), else the common view of the (train)
    ``cameras``, else the axis-convergence default. Never ground truth: synthetic scenes get
    exactly what a real capture would."""
    if sfm_points is not None:
        ranges = depth_ranges_from_points(sfm_points, cameras)
        if ranges is not None:
            return ranges, "sfm points"
    ranges = depth_ranges_from_rig(cameras)
    if ranges is not None:
        return ranges, "common view of the train cameras"
    return default_depth_ranges(cameras), "axis convergence default"


def default_depth_ranges(cameras: Sequence[Camera]) -> list[tuple[float, float]]:
    """Without points or a common view: the least-squares point closest to all optical axes is
    where a converging rig looks; the range spans a factor around its distance. For parallel
    axes (forward-facing rigs) the range is a multiple of the rig radius."""
    A, b = axes_system(cameras)
    extent = rig_extent(list(cameras))
    converging = axes_converge(cameras)
    out = []
    if converging:
        x = np.linalg.solve(A, b)
        for cam in cameras:
            z = float(cam.world_to_camera(x[None])[0, 2])
            if z > 0:
                out.append((z / C.MVS_DEFAULT_RANGE_FACTOR, z * C.MVS_DEFAULT_RANGE_FACTOR))
            else:
                converging = False
                break
    if not converging:
        out = [(C.MVS_PARALLEL_NEAR_EXTENT * extent, C.MVS_PARALLEL_FAR_EXTENT * extent)] * len(cameras)
    return out


# ---- plane sweep ------------------------------------------------------------------------------
@dataclass
class PlaneSweepConfig:
    """planes: inverse-depth hypotheses. scale: working resolution relative to the input.
    window: ZNCC window side (odd). topk: best source views averaged per plane. aggregation:
    box side of cost aggregation (1 = none). chunk: planes per chunk (memory bound).
    min_score / min_distinct / min_patch_std: validity thresholds (see constants). geo_*:
    forward-backward consistency (pixels, relative depth, views; geo_min_views 0 disables).
    num_threads: reference views swept in parallel, one torch thread each (0 = every core)."""

    planes: int = C.MVS_DEFAULT_PLANES
    scale: float = 1.0
    window: int = C.MVS_DEFAULT_WINDOW
    topk: int = C.MVS_DEFAULT_TOPK
    aggregation: int = C.MVS_DEFAULT_AGGREGATION
    chunk: int = C.MVS_DEFAULT_CHUNK
    min_score: float = C.MVS_MIN_SCORE
    min_distinct: float = C.MVS_MIN_DISTINCT
    min_patch_std: float = C.MVS_MIN_PATCH_STD
    geo_pixel_tol: float = C.MVS_GEO_PIXEL_TOL
    geo_depth_tol: float = C.MVS_GEO_DEPTH_TOL
    geo_min_views: int = C.MVS_GEO_MIN_VIEWS
    num_threads: int = 0

    def check(self) -> None:
        if self.planes < 3:
            raise InputError(f"MVS planes must be >= 3 (got {self.planes}); use e.g. --planes 64")
        if not 0 < self.scale <= 4:
            raise InputError(f"MVS scale must be in (0, 4] (got {self.scale}); e.g. --mvs-scale 0.5")
        if self.window < 3 or self.window % 2 == 0:
            raise InputError(f"MVS window must be odd and >= 3 (got {self.window})")
        if self.aggregation < 1 or self.aggregation % 2 == 0:
            raise InputError(f"MVS aggregation window must be odd and >= 1 (got {self.aggregation})")
        if self.topk < 1 or self.chunk < 1:
            raise InputError(f"MVS topk and chunk must be >= 1 (got {self.topk}, {self.chunk})")


@contextlib.contextmanager
def torch_threads(n: int) -> Iterator[None]:
    """Run with n torch threads (0 = every core), restoring the previous setting."""
    old = torch.get_num_threads()
    torch.set_num_threads(n if n > 0 else (os.cpu_count() or 1))
    try:
        yield
    finally:
        torch.set_num_threads(old)


def _box(x: torch.Tensor, k: int) -> torch.Tensor:
    """Mean over a k x k window of (B, C, H, W), shrinking at the borders (no zero padding bias)."""
    if k <= 1:
        return x
    # separable: the per-axis border counts multiply to the 2D count, so the mean stays exact
    x = F.avg_pool2d(x, (1, k), stride=1, padding=(0, k // 2), count_include_pad=False)
    return F.avg_pool2d(x, (k, 1), stride=1, padding=(k // 2, 0), count_include_pad=False)


def _gray(img: np.ndarray) -> np.ndarray:
    img = np.nan_to_num(np.asarray(img, np.float32), nan=0.0, posinf=1.0, neginf=0.0)
    return (img[..., 0] * 0.299 + img[..., 1] * 0.587 + img[..., 2] * 0.114).astype(np.float32)


def _resize(img: np.ndarray, cam: Camera) -> np.ndarray:
    import cv2

    if img.shape[:2] == (cam.height, cam.width):
        return img
    return cv2.resize(img, (cam.width, cam.height), interpolation=cv2.INTER_AREA)


class PlaneSweepMVS:
    """Plane-sweep stereo with ZNCC in torch (see the module docstring)."""

    name = "planesweep"

    def __init__(self, config: PlaneSweepConfig | None = None) -> None:
        self.config = config or PlaneSweepConfig()
        self.config.check()

    # -- public --------------------------------------------------------------------------
    def estimate(self, images: Sequence[np.ndarray], cameras: Sequence[Camera],
                 depth_ranges: Sequence[tuple[float, float]] | None = None, progress: bool = False) -> list[DepthResult]:
        cfg = self.config
        views = _check_views(images, cameras)
        cams = [c.scaled(cfg.scale) if cfg.scale != 1.0 else c for c in cameras]
        ranges = list(depth_ranges) if depth_ranges is not None else default_depth_ranges(cams)
        if len(ranges) != views:
            raise InputError(f"{len(ranges)} depth ranges for {views} views; pass one (near, far) per view")
        for i, (near, far) in enumerate(ranges):
            if not (np.isfinite(near) and np.isfinite(far) and 0 < near < far):
                raise InputError(f"view {i}: depth range ({near}, {far}) must satisfy 0 < near < far")
        workers = cfg.num_threads if cfg.num_threads > 0 else (os.cpu_count() or 1)
        # Parallel over reference views, one torch thread each: the ops release the GIL, and
        # unlike torch's intra-op OpenMP threads they do not spin-wait when cores are shared.
        with torch_threads(1), torch.no_grad(), ThreadPoolExecutor(max(1, min(workers, views))) as pool:
            grays = [torch.from_numpy(_gray(_resize(np.asarray(im, np.float32), c)))[None, None]
                     for im, c in zip(images, cams)]

            def sweep(r: int):
                with torch.no_grad():
                    return self._sweep(r, grays, cams, ranges[r])

            iterator = pool.map(sweep, range(views))
            if progress:
                from tqdm import tqdm

                iterator = tqdm(iterator, total=views, desc="plane sweep", unit="view", leave=False)
            raw = list(iterator)
            depths = [d for d, _, _ in raw]
            valids = [v for _, v, _ in raw]
            if cfg.geo_min_views > 0:
                valids = geometric_consistency(depths, valids, cams, cfg.geo_pixel_tol, cfg.geo_depth_tol,
                                               cfg.geo_min_views)
        out = []
        for (depth, _, conf), valid, cam in zip(raw, valids, cams):
            d = torch.where(valid, depth, torch.zeros_like(depth))
            out.append(DepthResult(d.numpy().astype(np.float32), valid.numpy().copy(),
                                   torch.where(valid, conf, torch.zeros_like(conf)).numpy().astype(np.float32), cam))
        return out

    # -- one reference view ------------------------------------------------------------------
    def _sweep(self, r: int, grays: list[torch.Tensor], cams: Sequence[Camera],
               depth_range: tuple[float, float]) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        cfg = self.config
        ref = grays[r]
        cam_r = cams[r]
        H, W = cam_r.height, cam_r.width
        P = cfg.planes
        sources = [s for s in range(len(cams)) if s != r]
        k = min(cfg.topk, len(sources))
        mu_r = _box(ref, cfg.window)
        var_r = (_box(ref * ref, cfg.window) - mu_r * mu_r).clamp_min(0.0)
        textured = var_r[0, 0].sqrt() >= cfg.min_patch_std
        # plane k has inverse depth w_k = w_near + k * dw (w decreasing towards far)
        w_near, w_far = 1.0 / depth_range[0], 1.0 / depth_range[1]
        dw = (w_far - w_near) / (P - 1)
        # per source: x_s ~ A p + w b, p = (u + 0.5, v + 0.5, 1) a reference pixel centre
        pix = torch.from_numpy(cam_r.pixel_centers().reshape(-1, 2))
        ph = torch.cat([pix, torch.ones(pix.shape[0], 1, dtype=pix.dtype)], 1).T  # (3, HW) float64
        geo = []
        for s in sources:
            cam_s = cams[s]
            rel = cam_s.w2c @ cam_r.c2w  # reference camera -> source camera
            Ks = torch.tensor(cam_s.K)
            A = Ks @ torch.tensor(rel[:3, :3] @ np.linalg.inv(cam_r.K)) @ ph
            b = Ks @ torch.tensor(rel[:3, 3])
            geo.append((A.to(torch.float32), b.to(torch.float32), cam_s.width, cam_s.height))

        best = torch.full((H, W), -np.inf)
        best_idx = torch.zeros((H, W), dtype=torch.long)
        best_prev = torch.full((H, W), np.nan)
        best_next = torch.full((H, W), np.nan)
        score_sum = torch.zeros((H, W))
        for a in range(0, P, cfg.chunk):
            b_end = min(a + cfg.chunk, P)
            lo, hi = max(a - 1, 0), min(b_end + 1, P)
            ws = (w_near + dw * torch.arange(lo, hi, dtype=torch.float64)).to(torch.float32)
            scores = self._plane_scores(ref, mu_r, var_r, grays, sources, geo, ws, k)  # (hi-lo, H, W)
            # pad with NaN where the chunk touches the ends of the sweep (no neighbour there)
            if lo == a:
                scores = torch.cat([torch.full((1, H, W), np.nan), scores])
            if hi == b_end:
                scores = torch.cat([scores, torch.full((1, H, W), np.nan)])
            inner = scores[1:-1]
            score_sum += inner.sum(0)
            val, arg = inner.max(0)
            prev = scores.gather(0, arg[None])[0]
            nxt = scores.gather(0, (arg + 2)[None])[0]
            upd = val > best
            best = torch.where(upd, val, best)
            best_idx = torch.where(upd, arg + a, best_idx)
            best_prev = torch.where(upd, prev, best_prev)
            best_next = torch.where(upd, nxt, best_next)

        # parabola through (-1, prev), (0, best), (+1, next): vertex offset in plane units
        curv = best_prev - 2.0 * best + best_next
        offset = 0.5 * (best_prev - best_next) / curv
        offset = torch.where(torch.isfinite(offset) & (curv < 0), offset.clamp(-0.5, 0.5), torch.zeros_like(offset))
        w = w_near + dw * (best_idx.to(torch.float64) + offset.to(torch.float64))
        depth = (1.0 / w).to(torch.float32)
        mean = score_sum / P
        gap = best - mean
        conf = best.clamp(0.0, 1.0) * (gap / (1.0 - mean).clamp_min(1e-6)).clamp(0.0, 1.0)
        interior = (best_idx > 0) & (best_idx < P - 1)  # a winner on the range border is likely outside it
        valid = textured & (best >= cfg.min_score) & (gap >= cfg.min_distinct) & interior & torch.isfinite(depth)
        valid &= depth > 0
        return depth, valid, conf.to(torch.float32)

    def _plane_scores(self, ref, mu_r, var_r, grays, sources, geo, ws, k) -> torch.Tensor:
        """Aggregated top-k ZNCC for the planes with inverse depths ``ws`` -> (len(ws), H, W)."""
        cfg = self.config
        _, _, H, W = ref.shape
        n = ws.shape[0]
        per_source = []
        for s, (A, b, Ws, Hs) in zip(sources, geo):
            x = A[None] + ws[:, None, None] * b[None, :, None]  # (n, 3, HW)
            z = x[:, 2]
            u = x[:, 0] / z
            v = x[:, 1] / z
            inside = (z > 0) & (u >= 0) & (u <= Ws) & (v >= 0) & (v <= Hs)
            grid = torch.stack([2.0 * u / Ws - 1.0, 2.0 * v / Hs - 1.0], -1).to(torch.float32)
            grid = torch.where(inside[..., None], grid, torch.full_like(grid, -2.0))
            warped = F.grid_sample(grays[s], grid.reshape(1, n * H, W, 2), mode="bilinear",
                                   padding_mode="zeros", align_corners=False).reshape(n, 1, H, W)
            ins = inside.to(torch.float32).reshape(n, 1, H, W)
            # one pooling call for the four windowed means
            means = _box(torch.cat([warped, warped * warped, warped * ref, ins], 1), cfg.window)
            mu_s = means[:, 0:1]
            var_s = (means[:, 1:2] - mu_s * mu_s).clamp_min(0.0)
            cross = means[:, 2:3] - mu_s * mu_r
            zncc = cross / torch.sqrt(var_s * var_r + C.MVS_ZNCC_EPS)
            usable = means[:, 3:4] >= C.MVS_MIN_INSIDE
            per_source.append(torch.where(usable, zncc, torch.full_like(zncc, -1.0))[:, 0])
        stack = torch.stack(per_source, 0)  # (S, n, H, W)
        score = stack.topk(k, dim=0).values.mean(0) if k < stack.shape[0] else stack.mean(0)
        return _box(score[:, None], cfg.aggregation)[:, 0]


def geometric_consistency(depths: list[torch.Tensor], valids: list[torch.Tensor], cams: Sequence[Camera],
                          pixel_tol: float, depth_tol: float, min_views: int) -> list[torch.Tensor]:
    """Forward-backward check: a reference depth stays valid when at least ``min_views`` other
    views, sampled where it projects, re-project back within ``pixel_tol`` pixels and
    ``depth_tol`` relative depth."""
    out = []
    for r, cam_r in enumerate(cams):
        d_r = depths[r].to(torch.float64)
        v_r = valids[r]
        H, W = d_r.shape
        idx = torch.nonzero(v_r.reshape(-1)).squeeze(1)
        count = torch.zeros(idx.shape[0], dtype=torch.int32)
        if idx.numel() == 0:
            out.append(v_r.clone())
            continue
        pix = torch.from_numpy(cam_r.pixel_centers().reshape(-1, 2))[idx]
        z = d_r.reshape(-1)[idx]
        X = _backproject(cam_r, pix, z)
        for s, cam_s in enumerate(cams):
            if s == r:
                continue
            uv_s, z_s = _project(cam_s, X)
            iu = torch.floor(uv_s[:, 0]).long()
            iv = torch.floor(uv_s[:, 1]).long()
            ok = (z_s > 0) & (iu >= 0) & (iu < cam_s.width) & (iv >= 0) & (iv < cam_s.height)
            ok &= torch.isfinite(uv_s).all(1)
            flat = (iv.clamp(0, cam_s.height - 1) * cam_s.width + iu.clamp(0, cam_s.width - 1))
            d_s = depths[s].to(torch.float64).reshape(-1)[flat]
            ok &= valids[s].reshape(-1)[flat]
            Y = _backproject(cam_s, uv_s, d_s)
            uv_back, z_back = _project(cam_r, Y)
            err = torch.linalg.norm(uv_back - pix, dim=1)
            rel = (z_back - z).abs() / z
            ok &= (err < pixel_tol) & (rel < depth_tol)
            count += ok.to(torch.int32)
        keep = torch.zeros(H * W, dtype=torch.bool)
        keep[idx] = count >= min_views
        out.append(keep.reshape(H, W))
    return out


def _backproject(cam: Camera, uv: torch.Tensor, z: torch.Tensor) -> torch.Tensor:
    Kinv = torch.from_numpy(np.linalg.inv(cam.K))
    rays = torch.cat([uv, torch.ones(uv.shape[0], 1, dtype=uv.dtype)], 1) @ Kinv.T
    pc = rays * z[:, None]
    return pc @ torch.tensor(cam.R).T + torch.tensor(cam.c2w[:3, 3])


def _project(cam: Camera, X: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    w2c = torch.tensor(cam.w2c)
    pc = X @ w2c[:3, :3].T + w2c[:3, 3]
    z = pc[:, 2]
    uvw = pc @ torch.tensor(cam.K).T
    uv = uvw[:, :2] / uvw[:, 2:3]
    return uv, z


def _check_views(images: Sequence[np.ndarray], cameras: Sequence[Camera]) -> int:
    if len(images) != len(cameras):
        raise InputError(f"{len(images)} images but {len(cameras)} cameras; pass one camera per image")
    if len(images) < 2:
        raise InputError(f"multi-view stereo needs at least 2 views, got {len(images)}")
    for img, cam in zip(images, cameras):
        shape = np.asarray(img).shape
        if len(shape) != 3 or shape[2] != 3:
            raise InputError(f"camera {cam.name!r}: image must be (H, W, 3) RGB, got shape {shape}")
        if shape[:2] != (cam.height, cam.width):
            raise InputError(f"camera {cam.name!r}: image is {shape[0]}x{shape[1]} but the camera is "
                             f"{cam.height}x{cam.width}; resize the image or use Camera.resized")
    return len(images)


# ---- MVSAnywhere ---------------------------------------------------------------------------------
@dataclass
class MVSAnywhereConfig:
    """weights_path: local checkpoint (e.g. mvsanywhere_hero.ckpt), default from the
    FIXER4D_MVSANYWHERE_WEIGHTS environment variable. config_file: the model YAML of the
    mvsanywhere repository (configs/models/mvsanywhere_model.yaml), default from
    FIXER4D_MVSANYWHERE_CONFIG. device: torch device. image_width/height: network input size
    (the package's defaults)."""

    weights_path: str | None = None
    config_file: str | None = None
    device: str = "cuda"
    image_width: int = 512
    image_height: int = 384


class MVSAnywhereEstimator:
    """Adapter around the ``mvsanywhere`` package: each view is the key view, the others its
    sources. No fallback: a missing package, weights file or config raises BackendUnavailable."""

    name = "mvsanywhere"

    def __init__(self, config: MVSAnywhereConfig | None = None) -> None:
        self.config = config or MVSAnywhereConfig()
        weights = self.config.weights_path or os.environ.get(MVSANYWHERE_WEIGHTS_ENV)
        cfg_file = self.config.config_file or os.environ.get(MVSANYWHERE_CONFIG_ENV)
        missing = []
        try:
            import mvsanywhere  # noqa: F401
        except ImportError:
            missing.append("the `mvsanywhere` Python package (pip install it from github.com/nianticlabs/mvsanywhere)")
        if not weights:
            missing.append(f"a weights path (MVSAnywhereConfig.weights_path or ${MVSANYWHERE_WEIGHTS_ENV})")
        elif not os.path.isfile(weights):
            missing.append(f"the weights file {weights} (it does not exist)")
        if not cfg_file:
            missing.append(f"the model config YAML (MVSAnywhereConfig.config_file or ${MVSANYWHERE_CONFIG_ENV})")
        elif not os.path.isfile(cfg_file):
            missing.append(f"the model config {cfg_file} (it does not exist)")
        if missing:
            raise BackendUnavailable("MVSAnywhere is unavailable; missing: " + "; ".join(missing)
                                     + ". Use the built-in plane sweep (--estimator planesweep) instead.")
        self.weights = weights
        self.config_file = cfg_file
        self._model = None

    def _load(self):
        if self._model is None:
            from mvsanywhere import options
            from mvsanywhere.utils.model_utils import get_model_class, load_model_inference

            handler = options.OptionsHandler()
            handler.parse_and_merge_options(config_filepaths=self.config_file, ignore_cl_args=True)
            opts = handler.options
            opts.load_weights_from_checkpoint = self.weights
            model = load_model_inference(opts, get_model_class(opts))
            self._model = model.to(self.config.device).eval()
            self._matching_scale = float(opts.matching_scale)
        return self._model

    def estimate(self, images: Sequence[np.ndarray], cameras: Sequence[Camera],
                 depth_ranges: Sequence[tuple[float, float]] | None = None, progress: bool = False) -> list[DepthResult]:
        import cv2

        views = _check_views(images, cameras)
        model = self._load()
        cfg = self.config
        dev = torch.device(cfg.device)
        mean = torch.tensor([0.485, 0.456, 0.406], device=dev)[:, None, None]
        std = torch.tensor([0.229, 0.224, 0.225], device=dev)[:, None, None]
        tens, Ks, c2ws = [], [], []
        for img, cam in zip(images, cameras):
            small = cv2.resize(np.asarray(img, np.float32), (cfg.image_width, cfg.image_height),
                               interpolation=cv2.INTER_AREA)
            tens.append((torch.from_numpy(small).permute(2, 0, 1).to(dev) - mean) / std)
            K = np.eye(4)
            K[:3, :3] = cam.resized(cfg.image_width, cfg.image_height).K
            K[:2] *= self._matching_scale
            Ks.append(torch.from_numpy(K).float().to(dev))
            c2ws.append(torch.tensor(cam.c2w).float().to(dev))
        results = []
        with torch.inference_mode():
            for r in range(views):
                src = [s for s in range(views) if s != r]

                def pack(ids, batch_dims):
                    img = torch.stack([tens[i] for i in ids])
                    K = torch.stack([Ks[i] for i in ids])
                    pose = torch.stack([c2ws[i] for i in ids])
                    d = {"image_b3hw": img, "world_T_cam_b44": pose, "cam_T_world_b44": torch.linalg.inv(pose),
                         "K_matching_b44": K, "invK_matching_b44": torch.linalg.inv(K)}
                    return {key: val.unsqueeze(0) if batch_dims else val for key, val in d.items()}

                cur = pack([r], False)
                if depth_ranges is not None:
                    cur["min_depth"] = torch.tensor([depth_ranges[r][0]], device=dev)
                    cur["max_depth"] = torch.tensor([depth_ranges[r][1]], device=dev)
                out = model(phase="test", cur_data=cur, src_data=pack(src, True),
                            unbatched_matching_encoder_forward=True, return_mask=True, num_refinement_steps=1)
                pred = out["depth_pred_s0_b1hw"][0, 0].float().cpu().numpy()
                cam = cameras[r].resized(pred.shape[1], pred.shape[0])
                valid = np.isfinite(pred) & (pred > 0)
                results.append(DepthResult(np.where(valid, pred, 0).astype(np.float32), valid,
                                           valid.astype(np.float32), cam))
        return results


def make_estimator(name: str, planesweep: PlaneSweepConfig | None = None,
                   mvsanywhere: MVSAnywhereConfig | None = None) -> DepthEstimator:
    """"planesweep" (built in) or "mvsanywhere" (optional package + local weights)."""
    if name == "planesweep":
        return PlaneSweepMVS(planesweep)
    if name == "mvsanywhere":
        return MVSAnywhereEstimator(mvsanywhere)
    raise InputError(f"unknown depth estimator {name!r}; choose planesweep or mvsanywhere")
