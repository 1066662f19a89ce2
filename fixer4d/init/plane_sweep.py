"""Plane-sweep stereo: ``PlaneSweepMVS`` (torch, CPU, deterministic), for every reference view:
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

Steps 2-3 are the matching cost (fixer4d.init.matching_cost), the region boxes and tiles are
fixer4d.init.sweep_regions, the geometric check fixer4d.init.consistency.
"""
from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Sequence

import numpy as np
import torch

from fixer4d.errors import InputError
from fixer4d.geometry.camera import Camera
import fixer4d.init.constants as C
from fixer4d.init.consistency import geometric_consistency
from fixer4d.init.depth_estimator import DepthResult, check_views
from fixer4d.init.depth_range import default_depth_ranges
from fixer4d.init.matching_cost import (RefView, SourceView, homography_terms, pixel_grid, plane_scores_kernel,
                                        plane_scores_torch)
from fixer4d.init.sweep_regions import crop_camera, roi_boxes, tile_axis, tile_planes
from fixer4d.threads import torch_threads


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
        """InputError naming the first setting out of its range."""
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


def _gray(img: np.ndarray) -> np.ndarray:
    """(H, W) float32 luma of an (H, W, 3) RGB image (non-finite values to 0 / 1)."""
    img = np.nan_to_num(np.asarray(img, np.float32), nan=0.0, posinf=1.0, neginf=0.0)
    return (img[..., 0] * 0.299 + img[..., 1] * 0.587 + img[..., 2] * 0.114).astype(np.float32)


def _resize(img: np.ndarray, cam: Camera) -> np.ndarray:
    """``img`` area-resampled to ``cam``'s size (unchanged when it has that size)."""
    import cv2

    if img.shape[:2] == (cam.height, cam.width):
        return img
    return cv2.resize(img, (cam.width, cam.height), interpolation=cv2.INTER_AREA)


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
        views = check_views(images, cameras)
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
        fine = [SourceView(torch.from_numpy(g)[None, None], c) for g, c in zip(grays, cams)]
        coarse = None
        if cfg.coarse_to_fine:
            ccams = [c.scaled(cfg.coarse_scale) for c in cams]
            coarse = [SourceView(torch.from_numpy(_resize(g, cc))[None, None], cc) for g, cc in zip(grays, ccams)]
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
    def _sweep(self, r: int, box: tuple[int, int, int, int], fine: list[SourceView], coarse: list[SourceView] | None,
               depth_range: tuple[float, float], roi: torch.Tensor | None = None
               ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Depth, validity and confidence of view ``r``'s pixels in ``box``, the other views'
        full images as sources. roi: optional (h, w) bool of the box, the pixels that need a
        depth (coarse-to-fine: the others are swept only at the coarse level, as context)."""
        import cv2

        cfg = self.config
        x0, y0, x1, y1 = box
        cam_r = crop_camera(fine[r].cam, box)
        ref = RefView(fine[r].gray[..., y0:y1, x0:x1], cfg.window, cfg.min_patch_std)
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
            ref_c = RefView(torch.from_numpy(_resize(ref.gray[0, 0].numpy(), cam_c))[None, None], cfg.coarse_window,
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

    def _full_sweep(self, ref: RefView, cam: Camera, sources: list[SourceView], w_near: float, dw: float, P: int
                    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
        """Every plane w_k = w_near + k dw, k < P, of one reference image (B = 1), streamed in
        chunks -> (inverse depth (H, W) float64 with the parabola's sub-plane offset, best score,
        winning plane, mean score)."""
        cfg = self.config
        H, W = ref.height, ref.width
        geo = [homography_terms(cam, s.cam, pixel_grid(0, 0, H, W)) for s in sources]
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

    def _tile_sweep(self, ref: RefView, cam: Camera, sources: list[SourceView], centre: torch.Tensor,
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
        tiles = [(ty, tx) for ty in tile_axis(H, C.MVS_TILE_PX, margin) for tx in tile_axis(W, C.MVS_TILE_PX, margin)]
        th, tw = min(H, C.MVS_TILE_PX + 2 * margin), min(W, C.MVS_TILE_PX + 2 * margin)
        plane_sets = [tile_planes(centre[ty[0]:ty[1], tx[0]:tx[1]], cfg.refine_band, P) for ty, tx in tiles]
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
            ref_t = RefView(torch.stack([ref.gray[0, :, py:py + th, px:px + tw] for py, px in pads]),
                            ref.window, cfg.min_patch_std)
            grid = torch.cat([pixel_grid(px, py, th, tw) for py, px in pads], 1)  # (2, B th tw)
            geo = [homography_terms(cam, s.cam, grid) for s in sources]
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

    def _scores(self, ref: RefView, sources: list[SourceView], geo, ws: torch.Tensor) -> torch.Tensor:
        """Aggregated top-k ZNCC of B reference tiles (``ref``, (B, 1, h, w)) on planes of inverse
        depth ``ws`` (n, B) (or (n, 1): the same planes for every tile) -> (n, B, h, w).
        geo: per source (A (3, B h w), b (3, 1)) from ``homography_terms``.

        The numba kernel (fixer4d.init.mvs_kernel) computes it when it can run, else
        ``plane_scores_torch``, the reference it is tested against."""
        scores = plane_scores_kernel if self._kernel else plane_scores_torch
        return scores(ref, sources, geo, ws, self.config.topk, self.config.aggregation)


def _upsample(x: np.ndarray, width: int, height: int) -> np.ndarray:
    """Bilinear resize of an (h, w) float map to (height, width), pixel centres aligned."""
    import cv2

    return cv2.resize(np.asarray(x, np.float32), (width, height), interpolation=cv2.INTER_LINEAR)


def _parabola_offset(prev: torch.Tensor, best: torch.Tensor, nxt: torch.Tensor) -> torch.Tensor:
    """Vertex of the parabola through (-1, prev), (0, best), (+1, next), in plane units within
    [-0.5, 0.5]; 0 where it is no maximum or a neighbour is missing (NaN). float64."""
    curv = prev - 2.0 * best + nxt
    offset = 0.5 * (prev - nxt) / curv
    ok = torch.isfinite(offset) & (curv < 0)
    return torch.where(ok, offset.clamp(-0.5, 0.5), torch.zeros_like(offset)).to(torch.float64)
