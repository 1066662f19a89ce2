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

Coarse-to-fine (default; ``refine_band=0`` is the single full sweep): steps 1-4 at half
resolution with planes x 0.5 planes (the same step in pixels) and a 3x3 window give each pixel a
plane; at full resolution each tile then sweeps only the full grid's planes within ``refine_band``
of its pixels' (fronto-parallel, with a window margin, so a score equals the full sweep's).
``estimate(..., rois=masks)`` sweeps each view only over its mask's region boxes, the other views'
full images as sources.

``MVSAnywhereEstimator`` runs the real ``mvsanywhere`` package (Izquierdo et al., CVPR 2025) when
it is importable and local weights are given; otherwise it raises BackendUnavailable.
"""
from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Protocol, Sequence, runtime_checkable

import numpy as np
import torch
import torch.nn.functional as F

from fixer4d.errors import BackendUnavailable, InputError
from fixer4d.geometry.camera import Camera, rig_extent
from fixer4d.geometry.rig import axes_converge, axes_system, common_view_bounds
from fixer4d.init import constants as C
from fixer4d.threads import torch_threads

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
    """planes: inverse-depth hypotheses of the full-resolution sweep. scale: working resolution
    relative to the input. window: ZNCC window side (odd). topk: best source views averaged per
    plane. aggregation: box side of cost aggregation (1 = none). chunk: planes per chunk (memory
    bound). min_score / min_distinct / min_patch_std: validity thresholds (see constants). geo_*:
    forward-backward consistency (pixels, relative depth, views; geo_min_views 0 disables).
    num_threads: sweeps run in parallel, one torch thread each (0 = every core).
    Coarse-to-fine: refine_band > 0 sweeps ``planes x coarse_scale`` planes at ``coarse_scale``
    x the working resolution (ZNCC window ``coarse_window``) first, then at the working
    resolution only 2 refine_band + 1 hypotheses per pixel around the coarse depth, spaced like
    the full grid's planes; refine_band 0 is the single full sweep of ``planes`` planes."""

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
    refine_band: int = C.MVS_REFINE_BAND
    coarse_scale: float = C.MVS_COARSE_SCALE
    coarse_window: int = C.MVS_COARSE_WINDOW

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
        if self.refine_band < 0:
            raise InputError(f"MVS refine_band must be >= 0 (got {self.refine_band}); 0 = one full sweep")
        if self.refine_band > 0 and not 0 < self.coarse_scale < 1:
            raise InputError(f"MVS coarse_scale must be in (0, 1) (got {self.coarse_scale}); or set refine_band=0")
        if self.coarse_window < 3 or self.coarse_window % 2 == 0:
            raise InputError(f"MVS coarse_window must be odd and >= 3 (got {self.coarse_window})")

    @property
    def coarse_to_fine(self) -> bool:
        """Whether the sweep is coarse-to-fine (a band narrower than the full plane grid)."""
        return self.refine_band > 0 and 2 * self.refine_band + 1 < self.planes

    @property
    def coarse_planes(self) -> int:
        """Planes of the coarse sweep: the full grid's step in pixels at the coarse resolution
        (fewer planes alias: the ZNCC peak falls between two planes)."""
        return max(3, int(round(self.planes * self.coarse_scale)))


def _box(x: torch.Tensor, k: int) -> torch.Tensor:
    """Mean over a k x k window of (B, C, H, W), shrinking at the borders (no zero padding bias).

    Separable sums of shifted slices added in place, divided by the per-pixel count of in-image
    taps: the per-axis counts multiply to the 2D count, so the mean is exact. (5x faster than
    ``avg_pool2d(count_include_pad=False)`` on CPU at 7x7, measured in one process.)"""
    if k <= 1:
        return x
    r = k // 2
    H, W = x.shape[-2:]
    s = x.clone()
    for i in range(1, min(r, W - 1) + 1):
        s[..., :-i] += x[..., i:]
        s[..., i:] += x[..., :-i]
    t = s.clone()
    for i in range(1, min(r, H - 1) + 1):
        t[..., :-i, :] += s[..., i:, :]
        t[..., i:, :] += s[..., :-i, :]
    return t.mul_(_inv_box_count(H, W, k))


def _inv_box_count(H: int, W: int, k: int) -> torch.Tensor:
    """(H, W) 1 / number of in-image taps of a k x k window centred on each pixel."""
    r = k // 2

    def axis(n: int) -> torch.Tensor:
        i = torch.arange(n)
        return (torch.minimum(i, torch.tensor(r)) + torch.minimum(n - 1 - i, torch.tensor(r)) + 1).to(torch.float32)

    return 1.0 / (axis(H)[:, None] * axis(W)[None, :])


def _gray(img: np.ndarray) -> np.ndarray:
    img = np.nan_to_num(np.asarray(img, np.float32), nan=0.0, posinf=1.0, neginf=0.0)
    return (img[..., 0] * 0.299 + img[..., 1] * 0.587 + img[..., 2] * 0.114).astype(np.float32)


def _resize(img: np.ndarray, cam: Camera) -> np.ndarray:
    import cv2

    if img.shape[:2] == (cam.height, cam.width):
        return img
    return cv2.resize(img, (cam.width, cam.height), interpolation=cv2.INTER_AREA)


def roi_boxes(mask: np.ndarray, margin: int) -> list[tuple[int, int, int, int]]:
    """Boxes (x0, y0, x1, y1) covering a region mask (H, W) bool: one per connected region of
    the mask widened by ``margin`` pixels (clipped to the image), boxes merged while a merge does
    not add pixels to sweep (union area <= the sum of both). Sorted; [] for an empty mask."""
    import cv2

    m = np.asarray(mask, bool).astype(np.uint8)
    if margin > 0:
        m = cv2.dilate(m, np.ones((2 * margin + 1, 2 * margin + 1), np.uint8))
    n, _, stats, _ = cv2.connectedComponentsWithStats(m, connectivity=8)
    boxes = [(int(x), int(y), int(x + w), int(y + h)) for x, y, w, h in stats[1:, :4]]

    def area(b):
        return (b[2] - b[0]) * (b[3] - b[1])

    merged = True
    while merged:
        merged = False
        for i in range(len(boxes)):
            for j in range(i + 1, len(boxes)):
                a, b = boxes[i], boxes[j]
                u = (min(a[0], b[0]), min(a[1], b[1]), max(a[2], b[2]), max(a[3], b[3]))
                if area(u) <= area(a) + area(b):
                    boxes[i] = u
                    del boxes[j]
                    merged = True
                    break
            if merged:
                break
    return sorted(boxes)


@dataclass
class _Source:
    """One source view at one pyramid level: (1, 1, H, W) gray and its camera."""

    gray: torch.Tensor
    cam: Camera


class PlaneSweepMVS:
    """Plane-sweep stereo with ZNCC in torch (see the module docstring)."""

    name = "planesweep"

    def __init__(self, config: PlaneSweepConfig | None = None, kernel: bool | None = None) -> None:
        """kernel: use the numba matching cost (None = whenever numba is importable); False
        keeps every sweep on the torch reference."""
        from fixer4d.init.mvs_kernel import unavailable_reason

        self.config = config or PlaneSweepConfig()
        self.config.check()
        self._kernel = unavailable_reason() is None if kernel is None else bool(kernel)

    # -- public --------------------------------------------------------------------------
    def estimate(self, images: Sequence[np.ndarray], cameras: Sequence[Camera],
                 depth_ranges: Sequence[tuple[float, float]] | None = None, progress: bool = False,
                 rois: Sequence[np.ndarray | None] | None = None, roi_margin: int = 0) -> list[DepthResult]:
        """Depth of every view. rois: optional V (H, W) bool masks at the input resolution (None =
        the view is only a source): each view is then swept only over the boxes of its mask's
        regions widened by ``roi_margin`` input pixels (``roi_boxes``), with the other views'
        full images as sources; pixels outside the boxes get no depth."""
        cfg = self.config
        views = _check_views(images, cameras)
        cams = [c.scaled(cfg.scale) if cfg.scale != 1.0 else c for c in cameras]
        ranges = list(depth_ranges) if depth_ranges is not None else default_depth_ranges(cams)
        if len(ranges) != views:
            raise InputError(f"{len(ranges)} depth ranges for {views} views; pass one (near, far) per view")
        for i, (near, far) in enumerate(ranges):
            if not (np.isfinite(near) and np.isfinite(far) and 0 < near < far):
                raise InputError(f"view {i}: depth range ({near}, {far}) must satisfy 0 < near < far")
        if rois is not None and len(rois) != views:
            raise InputError(f"{len(rois)} regions of interest for {views} views; pass one mask (or None) per view")
        grays = [_gray(_resize(np.asarray(im, np.float32), c)) for im, c in zip(images, cams)]
        fine = [_Source(torch.from_numpy(g)[None, None], c) for g, c in zip(grays, cams)]
        coarse = None
        if cfg.coarse_to_fine:
            ccams = [c.scaled(cfg.coarse_scale) for c in cams]
            coarse = [_Source(torch.from_numpy(_resize(g, cc))[None, None], cc) for g, cc in zip(grays, ccams)]
        # the sweeps: (view, box) with box = (x0, y0, x1, y1) at the working resolution
        tasks = []  # (view, box, the box's region mask or None = every pixel)
        for r, cam in enumerate(cams):
            if rois is None:
                tasks.append((r, (0, 0, cam.width, cam.height), None))
            elif rois[r] is not None:
                roi = np.asarray(rois[r], bool)
                if roi.shape != (cameras[r].height, cameras[r].width):
                    raise InputError(f"view {r}: region mask is {roi.shape}, the image "
                                     f"{(cameras[r].height, cameras[r].width)}")
                if roi.shape != (cam.height, cam.width):
                    import cv2

                    roi = cv2.resize(roi.astype(np.uint8), (cam.width, cam.height), interpolation=cv2.INTER_NEAREST) > 0
                margin = int(np.ceil(roi_margin * cfg.scale))
                tasks.extend((r, (x0, y0, x1, y1), torch.from_numpy(roi[y0:y1, x0:x1].copy()))
                             for x0, y0, x1, y1 in roi_boxes(roi, margin))
        workers = cfg.num_threads if cfg.num_threads > 0 else (os.cpu_count() or 1)
        if self._kernel:  # the kernel is parallel over planes and tiles itself
            workers = 1
        # Parallel over sweeps, one torch thread each: the ops release the GIL, and unlike
        # torch's intra-op OpenMP threads they do not spin-wait when cores are shared.
        with torch_threads(1), torch.no_grad(), ThreadPoolExecutor(max(1, min(workers, max(len(tasks), 1)))) as pool:

            def sweep(task):
                r, box, roi = task
                with torch.no_grad():
                    return self._sweep(r, box, fine, coarse, ranges[r], roi)

            iterator = pool.map(sweep, tasks)
            if progress:
                from tqdm import tqdm

                iterator = tqdm(iterator, total=len(tasks), desc="plane sweep", unit="sweep", leave=False)
            depths = [torch.zeros((c.height, c.width)) for c in cams]
            valids = [torch.zeros((c.height, c.width), dtype=torch.bool) for c in cams]
            confs = [torch.zeros((c.height, c.width)) for c in cams]
            for (r, (x0, y0, x1, y1), _), (d, v, cf) in zip(tasks, iterator):
                depths[r][y0:y1, x0:x1] = d
                valids[r][y0:y1, x0:x1] = v
                confs[r][y0:y1, x0:x1] = cf
            if cfg.geo_min_views > 0:
                valids = geometric_consistency(depths, valids, cams, cfg.geo_pixel_tol, cfg.geo_depth_tol,
                                               cfg.geo_min_views)
        out = []
        for depth, valid, conf, cam in zip(depths, valids, confs, cams):
            d = torch.where(valid, depth, torch.zeros_like(depth))
            out.append(DepthResult(d.numpy().astype(np.float32), valid.numpy().copy(),
                                   torch.where(valid, conf, torch.zeros_like(conf)).numpy().astype(np.float32), cam))
        return out

    # -- one reference image ------------------------------------------------------------------
    def _sweep(self, r: int, box: tuple[int, int, int, int], fine: list[_Source], coarse: list[_Source] | None,
               depth_range: tuple[float, float], roi: torch.Tensor | None = None
               ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Depth, validity and confidence of view ``r``'s pixels in ``box``, the other views'
        full images as sources. roi: optional (h, w) bool of the box, the pixels that need a
        depth (coarse-to-fine: the others are swept only at the coarse level, as context)."""
        import cv2

        cfg = self.config
        x0, y0, x1, y1 = box
        cam_r = crop_camera(fine[r].cam, box)
        ref = _RefView(fine[r].gray[..., y0:y1, x0:x1], cfg.window, cfg.min_patch_std)
        H, W = ref.height, ref.width
        P = cfg.planes
        w_near, w_far = 1.0 / depth_range[0], 1.0 / depth_range[1]
        dw = (w_far - w_near) / (P - 1)
        sources = [fine[s] for s in range(len(fine)) if s != r]
        if coarse is None:
            w, best, idx, mean = self._full_sweep(ref, cam_r, sources, w_near, dw, P)
            in_band = torch.ones_like(best, dtype=torch.bool)
        else:
            # coarse: every plane of a sparser grid at reduced resolution -> an inverse depth per pixel
            cam_c = cam_r.scaled(cfg.coarse_scale)
            ref_c = _RefView(torch.from_numpy(_resize(ref.gray[0, 0].numpy(), cam_c))[None, None], cfg.coarse_window,
                             cfg.min_patch_std)
            Pc = cfg.coarse_planes
            w_c, best_c, _, mean_c = self._full_sweep(ref_c, cam_c, [coarse[s] for s in range(len(coarse)) if s != r],
                                                      w_near, (w_far - w_near) / (Pc - 1), Pc)
            # fine: per tile, the full grid's planes within refine_band of its pixels' coarse depths
            # (median-filtered against outliers, upsampled)
            w_up = _upsample(cv2.medianBlur(w_c.numpy().astype(np.float32), C.MVS_COARSE_MEDIAN), W, H)
            centre = torch.from_numpy((w_up.astype(np.float64) - w_near) / dw).round().long().clamp(0, P - 1)
            # planes are needed only by textured pixels with some match at the coarse level
            matched = torch.from_numpy(_upsample(best_c.numpy(), W, H)) >= C.MVS_COARSE_MIN_SCORE
            wanted = ref.textured[0] & matched if roi is None else ref.textured[0] & matched & roi
            need = torch.where(wanted, centre, torch.full_like(centre, -1))
            w, best, idx, in_band = self._tile_sweep(ref, cam_r, sources, need, w_near, dw, P)
            mean = torch.from_numpy(_upsample(mean_c.numpy(), W, H))  # the curve's mean, whole range
        depth = (1.0 / w).to(torch.float32)
        gap = best - mean
        conf = best.clamp(0.0, 1.0) * (gap / (1.0 - mean).clamp_min(1e-6)).clamp(0.0, 1.0)
        interior = (idx > 0) & (idx < P - 1)  # a winner on the range border is likely outside it
        valid = ref.textured[0] & (best >= cfg.min_score) & (gap >= cfg.min_distinct) & interior & in_band
        valid &= torch.isfinite(depth) & (depth > 0)
        return depth, valid, conf.to(torch.float32)

    def _full_sweep(self, ref: "_RefView", cam: Camera, sources: list[_Source], w_near: float, dw: float, P: int
                    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """Every plane w_k = w_near + k dw, k < P, of one reference image (B = 1), streamed in
        chunks -> (inverse depth (H, W) float64 with the parabola's sub-plane offset, best score,
        winning plane, mean score)."""
        cfg = self.config
        H, W = ref.height, ref.width
        geo = [_homography_terms(cam, s.cam, _pixel_grid(0, 0, H, W)) for s in sources]
        best = torch.full((H, W), -np.inf)
        best_idx = torch.zeros((H, W), dtype=torch.long)
        best_prev = torch.full((H, W), np.nan)
        best_next = torch.full((H, W), np.nan)
        score_sum = torch.zeros((H, W))
        for a in range(0, P, cfg.chunk):
            b_end = min(a + cfg.chunk, P)
            lo, hi = max(a - 1, 0), min(b_end + 1, P)
            ws = (w_near + dw * torch.arange(lo, hi, dtype=torch.float64)).to(torch.float32)[:, None]
            scores = self._scores(ref, sources, geo, ws)[:, 0]  # (hi-lo, H, W)
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
        w = w_near + dw * (best_idx.to(torch.float64) + _parabola_offset(best_prev, best, best_next))
        return w, best, best_idx, score_sum / P

    def _tile_sweep(self, ref: "_RefView", cam: Camera, sources: list[_Source], centre: torch.Tensor,
                    w_near: float, dw: float, P: int
                    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """Fronto-parallel planes of the full grid, per tile of MVS_TILE_PX pixels only those
        within refine_band of its pixels' ``centre`` planes (H, W) long (-1: needs none).

        Each tile is swept with a margin (ZNCC window + aggregation) on every side, so a pixel's
        score on a plane equals the full sweep's. Tiles are batched by their number of planes.
        Returns (inverse depth (H, W) float64 with the parabola's sub-plane offset, best score,
        winning plane, in_band: both neighbouring planes of the winner were swept)."""
        cfg = self.config
        H, W = ref.height, ref.width
        margin = ref.window // 2 + cfg.aggregation // 2
        tiles = [(ty, tx) for ty in _tile_axis(H, C.MVS_TILE_PX, margin) for tx in _tile_axis(W, C.MVS_TILE_PX, margin)]
        th, tw = min(H, C.MVS_TILE_PX + 2 * margin), min(W, C.MVS_TILE_PX + 2 * margin)
        plane_sets = [_tile_planes(centre[ty[0]:ty[1], tx[0]:tx[1]], cfg.refine_band, P) for ty, tx in tiles]
        w = torch.zeros((H, W), dtype=torch.float64)
        best = torch.full((H, W), -np.inf)
        idx = torch.zeros((H, W), dtype=torch.long)
        in_band = torch.zeros((H, W), dtype=torch.bool)
        groups: dict[int, list[int]] = {}
        for t, planes in enumerate(plane_sets):
            groups.setdefault(len(planes), []).append(t)
        groups.pop(0, None)  # tiles with nothing to sweep (every pixel textureless)
        for n, members in sorted(groups.items()):
            planes = torch.stack([plane_sets[t] for t in members], 1)  # (n, B) sorted per tile
            pads = [(tiles[t][0][2], tiles[t][1][2]) for t in members]
            ref_t = _RefView(torch.stack([ref.gray[0, :, py:py + th, px:px + tw] for py, px in pads]),
                             ref.window, cfg.min_patch_std)
            grid = torch.cat([_pixel_grid(px, py, th, tw) for py, px in pads], 1)  # (2, B th tw)
            geo = [_homography_terms(cam, s.cam, grid) for s in sources]
            scores = torch.empty((n, len(members), th, tw))
            for a in range(0, n, cfg.chunk):
                ws = (w_near + dw * planes[a:a + cfg.chunk].to(torch.float64)).to(torch.float32)
                scores[a:a + cfg.chunk] = self._scores(ref_t, sources, geo, ws)
            val, arg = scores.max(0)  # (B, th, tw)
            win = planes[:, :, None, None].expand(n, len(members), th, tw).gather(0, arg[None])[0]  # plane index
            nanpad = torch.full((1, len(members), th, tw), np.nan)
            padded = torch.cat([nanpad, scores, nanpad])
            prev = padded.gather(0, arg[None])[0]
            nxt = padded.gather(0, (arg + 2)[None])[0]
            pl = torch.cat([torch.full((1, len(members)), -10), planes, torch.full((1, len(members)), -10)])
            pl = pl[:, :, None, None].expand(n + 2, len(members), th, tw)
            has_prev = pl.gather(0, arg[None])[0] == win - 1  # the swept neighbour is the adjacent plane
            has_next = pl.gather(0, (arg + 2)[None])[0] == win + 1
            prev = torch.where(has_prev, prev, torch.full_like(prev, np.nan))
            nxt = torch.where(has_next, nxt, torch.full_like(nxt, np.nan))
            w_t = w_near + dw * (win.to(torch.float64) + _parabola_offset(prev, val, nxt))
            for b, t in enumerate(members):
                (y0, y1, py), (x0, x1, px) = tiles[t]
                sl = (slice(y0 - py, y1 - py), slice(x0 - px, x1 - px))
                w[y0:y1, x0:x1] = w_t[b][sl]
                best[y0:y1, x0:x1] = val[b][sl]
                idx[y0:y1, x0:x1] = win[b][sl]
                in_band[y0:y1, x0:x1] = (has_prev & has_next)[b][sl] | (win[b][sl] == 0) | (win[b][sl] == P - 1)
        return w, best, idx, in_band

    def _scores(self, ref: "_RefView", sources: list[_Source], geo, ws: torch.Tensor) -> torch.Tensor:
        """Aggregated top-k ZNCC of B reference tiles (``ref``, (B, 1, h, w)) on planes of inverse
        depth ``ws`` (n, B) (or (n, 1): the same planes for every tile) -> (n, B, h, w).
        geo: per source (A (3, B h w), b (3, 1)) from ``_homography_terms``.

        The numba kernel (fixer4d.init.mvs_kernel) computes it when it can run, else
        ``_scores_torch``, the reference it is tested against."""
        if self._kernel:
            return _scores_kernel(ref, sources, geo, ws, self.config)
        return self._scores_torch(ref, sources, geo, ws)

    def _scores_torch(self, ref: "_RefView", sources: list[_Source], geo, ws: torch.Tensor) -> torch.Tensor:
        """``_scores`` in torch ops."""
        cfg = self.config
        B, h, w = ref.gray.shape[0], ref.height, ref.width
        n = ws.shape[0]
        k = min(cfg.topk, len(sources))
        per_source = []
        total = worst = None
        for src, (A, b) in zip(sources, geo):
            Ws, Hs = src.cam.width, src.cam.height
            A = A.reshape(3, 1, B, h * w)
            wb = ws[:, :, None]  # (n, B, 1)
            z = A[2] + wb * b[2]  # (n, B, hw)
            grid = torch.empty((n, B, h * w, 2))
            u, v = grid[..., 0], grid[..., 1]
            torch.div(A[0] + wb * b[0], z, out=u)
            torch.div(A[1] + wb * b[1], z, out=v)
            inside = (z > 0) & (u >= 0) & (u <= Ws) & (v >= 0) & (v <= Hs)
            u.mul_(2.0 / Ws).sub_(1.0)
            v.mul_(2.0 / Hs).sub_(1.0)
            grid.masked_fill_(~inside[..., None], -2.0)
            warped = F.grid_sample(src.gray, grid.view(1, n * B * h, w, 2), mode="bilinear",
                                   padding_mode="zeros", align_corners=False).view(n, B, h, w)
            # one box filter for the windowed means (and the inside share where a warp leaves the image)
            c = 3 if bool(inside.all()) else 4
            buf = torch.empty((n * B, c, h, w))
            bv = buf.view(n, B, c, h, w)
            bv[:, :, 0] = warped
            torch.mul(warped, warped, out=bv[:, :, 1])
            torch.mul(warped, ref.gray[:, 0], out=bv[:, :, 2])
            if c == 4:
                bv[:, :, 3] = inside.view(n, B, h, w)
            means = _box(buf, ref.window).view(n, B, c, h, w)
            mu_s = means[:, :, 0]
            var_s = (means[:, :, 1] - mu_s * mu_s).clamp_min_(0.0)
            cross = means[:, :, 2] - mu_s * ref.mu
            zncc = cross.div_(torch.sqrt(var_s.mul_(ref.var).add_(C.MVS_ZNCC_EPS)))
            if c == 4:
                zncc.masked_fill_(means[:, :, 3] < C.MVS_MIN_INSIDE, -1.0)
            if k == len(sources) - 1:  # the mean of all but the worst source: running sum and minimum
                total = zncc.clone() if total is None else total.add_(zncc)
                worst = zncc if worst is None else torch.minimum(worst, zncc)
            else:
                per_source.append(zncc)
        if per_source:
            stack = torch.stack(per_source, 0)  # (S, n, B, h, w)
            score = stack.mean(0) if k == stack.shape[0] else stack.topk(k, dim=0).values.mean(0)
        else:
            score = total.sub_(worst).div_(k)
        return _box(score.reshape(n * B, 1, h, w), cfg.aggregation).reshape(n, B, h, w)


def _scores_kernel(ref: "_RefView", sources: list[_Source], geo, ws: torch.Tensor,
                   cfg: PlaneSweepConfig) -> torch.Tensor:
    """``PlaneSweepMVS._scores`` through fixer4d.init.mvs_kernel.zncc_scores."""
    from fixer4d.init.mvs_kernel import zncc_scores
    from fixer4d.jit import torch_threads_kept

    B, h, w = ref.gray.shape[0], ref.height, ref.width
    S = len(sources)
    Hmax = max(s.cam.height for s in sources)
    Wmax = max(s.cam.width for s in sources)
    srcs = np.zeros((S, Hmax, Wmax), np.float32)
    size = np.zeros((S, 2), np.int64)
    for i, src in enumerate(sources):
        g = src.gray[0, 0].numpy()
        srcs[i, :g.shape[0], :g.shape[1]] = g
        size[i] = g.shape
    A = np.ascontiguousarray(np.stack([a.numpy() for a, _ in geo]), np.float32)
    bvec = np.ascontiguousarray(np.stack([b[:, 0].numpy() for _, b in geo]), np.float32)
    out = np.empty((ws.shape[0], B, h, w), np.float32)
    f32 = np.float32
    with torch_threads_kept():
        zncc_scores(np.ascontiguousarray(ref.gray[:, 0].numpy()), np.ascontiguousarray(ref.mu.numpy()),
                    np.ascontiguousarray(ref.var.numpy()), srcs, size, A, bvec,
                    np.ascontiguousarray(ws.numpy(), np.float32), ref.window, cfg.aggregation,
                    min(cfg.topk, S), f32(C.MVS_ZNCC_EPS), f32(C.MVS_MIN_INSIDE), out)
    return torch.from_numpy(out)


class _RefView:
    """B reference images or tiles (B, 1, h, w) with their windowed mean, variance (B, h, w)
    and texture test."""

    def __init__(self, gray: torch.Tensor, window: int, min_patch_std: float) -> None:
        self.gray = gray.contiguous()
        self.height, self.width = gray.shape[-2:]
        self.window = window
        self.mu = _box(self.gray, window)[:, 0]
        self.var = (_box(self.gray * self.gray, window)[:, 0] - self.mu * self.mu).clamp_min(0.0)
        self.textured = self.var.sqrt() >= min_patch_std


def crop_camera(cam: Camera, box: tuple[int, int, int, int]) -> Camera:
    """The camera of the sub-image ``box`` = (x0, y0, x1, y1) (principal point shifted)."""
    x0, y0, x1, y1 = box
    if (x0, y0, x1, y1) == (0, 0, cam.width, cam.height):
        return cam
    K = cam.K.copy()
    K[0, 2] -= x0
    K[1, 2] -= y0
    return Camera(K, cam.c2w, x1 - x0, y1 - y0, cam.name)


def _upsample(x: np.ndarray, width: int, height: int) -> np.ndarray:
    """Bilinear resize of an (h, w) float map to (height, width), pixel centres aligned."""
    import cv2

    return cv2.resize(np.asarray(x, np.float32), (width, height), interpolation=cv2.INTER_LINEAR)


def _tile_axis(n: int, size: int, margin: int) -> list[tuple[int, int, int]]:
    """Tiles of one image axis of length n: (start, end, padded start) with inner extent
    [start, end) of at most ``size`` and a padded extent of min(n, size + 2 margin) from the
    padded start, kept inside the image (at the image border the window shrinks as it does in
    a whole-image sweep; elsewhere the padding holds the margin)."""
    padded = size + 2 * margin
    if n <= padded:
        return [(0, n, 0)]
    return [(a, min(a + size, n), min(max(a - margin, 0), n - padded)) for a in range(0, n, size)]


def _tile_planes(centre: torch.Tensor, band: int, P: int) -> torch.Tensor:
    """Sorted planes (long) a tile sweeps: every plane within ``band`` of one of its pixels'
    ``centre`` planes (-1 = a pixel that needs none), at most MVS_TILE_MAX_PLANES of them (then
    those serving the most pixels, ties to the nearer plane: a tile mixing many depths keeps its
    main surfaces)."""
    c = centre.reshape(-1)
    c = c[c >= 0]
    count = torch.zeros(P, dtype=torch.long)
    for off in range(-band, band + 1):
        count += torch.bincount((c + off).clamp(0, P - 1), minlength=P)
    planes = torch.nonzero(count).squeeze(1)
    if planes.numel() > C.MVS_TILE_MAX_PLANES:
        order = torch.argsort(count[planes], descending=True, stable=True)
        planes = planes[order[:C.MVS_TILE_MAX_PLANES]].sort().values
    return planes


def _pixel_grid(x0: int, y0: int, h: int, w: int) -> torch.Tensor:
    """(2, h w) float64 pixel centres (u + 0.5, v + 0.5) of the h x w block at (x0, y0)."""
    v, u = torch.meshgrid(torch.arange(y0, y0 + h, dtype=torch.float64) + 0.5,
                          torch.arange(x0, x0 + w, dtype=torch.float64) + 0.5, indexing="ij")
    return torch.stack([u.reshape(-1), v.reshape(-1)])


def _homography_terms(cam_r: Camera, cam_s: Camera, pix: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Source pixel x_s ~ A p + w b for reference pixel centres ``pix`` (2, N) (p = (u, v, 1),
    coordinates of ``cam_r``'s image) at inverse depth w: A (3, N), b (3, 1) float32."""
    ph = torch.cat([pix, torch.ones(1, pix.shape[1], dtype=pix.dtype)], 0)  # (3, N) float64
    rel = cam_s.w2c @ cam_r.c2w  # reference camera -> source camera
    Ks = torch.tensor(cam_s.K)
    A = (Ks @ torch.tensor(rel[:3, :3] @ np.linalg.inv(cam_r.K))) @ ph
    b = Ks @ torch.tensor(rel[:3, 3])
    return A.to(torch.float32), b.to(torch.float32)[:, None]


def _parabola_offset(prev: torch.Tensor, best: torch.Tensor, nxt: torch.Tensor) -> torch.Tensor:
    """Vertex of the parabola through (-1, prev), (0, best), (+1, next), in plane units within
    [-0.5, 0.5]; 0 where it is no maximum or a neighbour is missing (NaN). float64."""
    curv = prev - 2.0 * best + nxt
    offset = 0.5 * (prev - nxt) / curv
    ok = torch.isfinite(offset) & (curv < 0)
    return torch.where(ok, offset.clamp(-0.5, 0.5), torch.zeros_like(offset)).to(torch.float64)


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
