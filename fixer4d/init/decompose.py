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
               the view-dependent residual that decides the SH degree (fixer4d.model.terms)

Cost: the static plane sweep runs once for the clip; the per-frame sweeps cover only the moving
regions' boxes (15% of the demo's pixels, 34% of Panoptic's), so a clip costs about one
full-frame sweep plus the moving regions, instead of one full sweep per frame.

Modules: the motion seeds are fixer4d.init.tracks, the evidence fixer4d.init.evidence, the
visibility and sampling helpers fixer4d.init.view_sampling; this module runs them in order
(``decompose``) and writes the init folder (``run_decomposed``).

Output files in the init folder: ``decomposed.npz`` (``DecomposedInit.save``), ``masks.npz``
(fixer4d.init.masks format) and, for viewers and readers of per-frame clouds,
``frame_XXXX.ply`` = the static cloud plus that frame's moving points.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from fixer4d.atomic import atomic_path
from fixer4d.errors import InputError
from fixer4d.geometry.camera import Camera
import fixer4d.init.quality as Q
from fixer4d.init.cloud import FrameCloud, save_frame_clouds
from fixer4d.init.evidence import color_spread, sample_view_colors
from fixer4d.init.fusion import fuse_depths, fuse_results, scene_scale
from fixer4d.init.masks import MASKS_NAME, median_without, moving_masks_for_scene, save_masks, statistics_frames
from fixer4d.init.report import finish_report
from fixer4d.init.tracks import TRACK_HALF_FRAMES, FlowCache, local_angular_velocity, seed_motion
from fixer4d.init.view_sampling import resize_mask, visible_in
from fixer4d.model.camera_response import view_gains

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
    scene_scale: median viewing distance (world units).
    view_log_gain, view_gain_stderr: (V, 3) float32 each train view's colour gain relative to the
      rig (log units; fixer4d.model.camera_response.view_gains) and its standard error, from the
      static points several views see; (0, 3) when not measured. info: statistics for the report.
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
    view_log_gain: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.float32))
    view_gain_stderr: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.float32))
    info: dict[str, Any] = field(default_factory=dict)

    @property
    def num_static(self) -> int:
        return int(self.static_points.shape[0])

    @property
    def num_dynamic(self) -> int:
        return int(self.dyn_points.shape[0])

    def frame_clouds(self) -> list[FrameCloud]:
        """Per init frame: the static cloud plus that frame's moving points (viewers, readers of per-frame clouds)."""
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
        arrays = {k: np.asarray(getattr(self, k)) for k in _ARRAYS + _VIEW_ARRAYS}
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
                kw.update({k: z[k] for k in _VIEW_ARRAYS if k in z.files})
                return cls(**kw, scene_scale=float(z["scene_scale"]), info=json.loads(str(z["info"])))
        except (KeyError, ValueError, OSError) as exc:
            raise InputError(f"{path}: not a decomposed init ({exc}); delete the init folder and rerun") from None


_ARRAYS = ("frames", "times", "static_points", "static_colors", "static_view_std", "dyn_points", "dyn_colors",
           "dyn_times", "dyn_frames", "dyn_coeffs", "dyn_degree", "dyn_fit_px", "dyn_omega", "dyn_rot_gain")
# per-view arrays that are optional in the file (empty when absent: not measured)
_VIEW_ARRAYS = ("view_log_gain", "view_gain_stderr")


def has_decomposed(out_dir: str | Path) -> bool:
    """Whether ``out_dir`` holds a decomposed init (``decomposed.npz``)."""
    return (Path(out_dir) / DECOMPOSED_NAME).is_file()


# ---- the decomposition ----------------------------------------------------------------------------
def static_median(images: np.ndarray, moving: np.ndarray) -> np.ndarray:
    """Per-pixel temporal median over the frames where the pixel does not move.

    images: (F, H, W, 3) float32; moving: (F, H, W) bool. A pixel that moves in every frame
    falls back to the plain median. Returns (H, W, 3) float32.
    """
    exclude = np.array(moving, bool)
    exclude[:, exclude.all(0)] = False  # moving in every frame: the plain median
    return median_without(np.asarray(images, np.float32), exclude).astype(np.float32)



def _tick(timer, stage: str, t0: float) -> None:
    """Add the time since ``t0`` to ``stage`` of ``timer`` (fixer4d.init.report.Timer) when given."""
    if timer is not None:
        timer.add(stage, t0)


def _static_cloud(imgs: np.ndarray, masks: np.ndarray, cams: Sequence[Camera], estimator, ranges, fusion_config,
                  timer) -> tuple[list[np.ndarray], list, np.ndarray, np.ndarray]:
    """The clip's one static cloud: MVS once on each view's temporal median of its non-moving
    pixels, fused. imgs: (F, V, H, W, 3) float32; masks: (V, F, H, W) bool. Returns (the V median
    images (H, W, 3), their V DepthResults, points (N, 3), colours (N, 3))."""
    t0 = time.perf_counter()
    medians = [static_median(imgs[:, v], masks[v]) for v in range(len(cams))]
    _tick(timer, "static_median", t0)
    t0 = time.perf_counter()
    static_res = estimator.estimate(medians, list(cams), ranges)
    _tick(timer, "mvs", t0)
    t0 = time.perf_counter()
    s_pts, s_cols = fuse_results(medians, static_res, fusion_config)
    _tick(timer, "fusion", t0)
    return medians, static_res, s_pts, s_cols


def _frame_moving_points(frame_imgs: np.ndarray, frame_masks: np.ndarray, cams: Sequence[Camera], estimator, ranges,
                         fusion_config, timer) -> tuple[np.ndarray, np.ndarray, np.ndarray, int, int]:
    """One init frame's moving points: MVS over the boxes of each view's moving regions (the
    other views' full frames as sources; an estimator other than PlaneSweepMVS sweeps whole
    frames), depths kept where the view's mask says, fused.

    frame_imgs: (V, H, W, 3) float32; frame_masks: (V, H, W) bool. Views with fewer than
    MIN_MOVING_PIXELS moving pixels are sources only; fewer than 2 such views give no points.
    Returns (points (M, 3), colours (M, 3), visible (V, M) bool, views with moving content,
    pixels of the swept boxes)."""
    from fixer4d.init.plane_sweep import PlaneSweepMVS
    from fixer4d.init.sweep_regions import roi_boxes

    t0 = time.perf_counter()
    V = len(cams)
    rois = [frame_masks[v] if frame_masks[v].sum() >= MIN_MOVING_PIXELS else None for v in range(V)]
    use = [v for v in range(V) if rois[v] is not None]
    pts = np.zeros((0, 3), np.float32)
    cols = np.zeros((0, 3), np.float32)
    if len(use) < 2:
        _tick(timer, "mvs", t0)
        return pts, cols, np.zeros((V, 0), bool), len(use), 0
    crop_pixels = sum((x1 - x0) * (y1 - y0) for v in use for x0, y0, x1, y1 in roi_boxes(rois[v], CROP_MARGIN_PX))
    if isinstance(estimator, PlaneSweepMVS):  # sweeps only the regions, the full frames as sources
        res = estimator.estimate(list(frame_imgs), list(cams), ranges, rois=rois, roi_margin=CROP_MARGIN_PX)
    else:
        res = estimator.estimate(list(frame_imgs), list(cams), ranges)
    _tick(timer, "mvs", t0)
    t0 = time.perf_counter()
    valids = [r.valid & resize_mask(frame_masks[v], r.depth.shape) if rois[v] is not None
              else np.zeros(r.depth.shape, bool) for v, r in enumerate(res)]
    if sum(int(v.sum()) for v in valids) > 0:
        import cv2

        rimgs = [im if im.shape[:2] == r.depth.shape else
                 cv2.resize(im, (r.depth.shape[1], r.depth.shape[0]), interpolation=cv2.INTER_AREA)
                 for im, r in zip(frame_imgs, res)]
        pts, cols = fuse_depths(rimgs, [r.depth for r in res], [r.camera for r in res], valids, fusion_config)
    vis = np.zeros((V, len(pts)), bool)
    for v, r in enumerate(res):
        vis[v], _ = visible_in(pts, r.depth, valids[v], r.camera)
    _tick(timer, "fusion", t0)
    return pts, cols, vis, len(use), crop_pixels


def _motion_seeds(scene, frames: list[int], cams: Sequence[Camera], d_pts: list[np.ndarray], d_vis: list[np.ndarray],
                  dyn_points: np.ndarray, dyn_frames: np.ndarray, timer) -> tuple[dict[str, np.ndarray], int]:
    """Motion seeds of every frame's moving points (fixer4d.init.tracks): flow chained over
    TRACK_HALF_FRAMES neighbouring frames, triangulated, fitted, plus the local rigid rotation.

    d_pts / d_vis: per init frame, its moving points (M_j, 3) and where they are seen (V, M_j);
    dyn_points (M, 3) / dyn_frames (M,): all of them in frame order. Returns (DecomposedInit's
    fields dyn_coeffs (M, 3, 3), dyn_degree (M,), dyn_fit_px (M,), dyn_omega (M, 3),
    dyn_rot_gain (M,); the number of flow fields computed)."""
    V = len(cams)
    flows = FlowCache(lambda f, v: np.asarray(scene.frame(f, scene.train_ids[v]), np.float32))
    t0 = time.perf_counter()  # decoding the neighbouring frames is loading, not preparation
    for f in sorted({g for f in frames for g in range(f - TRACK_HALF_FRAMES, f + TRACK_HALF_FRAMES + 1)
                     if 0 <= g < scene.num_frames}):
        for v in range(V):
            flows.gray(v, f)
    _tick(timer, "load", t0)
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
    coeffs = np.concatenate(coeffs_l) if coeffs_l else np.zeros((0, 4, 3))
    degree = np.concatenate(deg_l) if deg_l else np.zeros(0, np.int8)
    rms = np.concatenate(rms_l) if rms_l else np.zeros(0)
    omega, rot_gain = local_angular_velocity(dyn_points.astype(np.float64), coeffs[:, 1], degree >= 1, dyn_frames)
    _tick(timer, "motion", t0)
    return {"dyn_coeffs": coeffs[:, 1:].astype(np.float32), "dyn_degree": degree.astype(np.int8),
            "dyn_fit_px": rms.astype(np.float32), "dyn_omega": omega.astype(np.float32),
            "dyn_rot_gain": rot_gain.astype(np.float32)}, flows.count


def decompose(scene, cams: Sequence[Camera], frames: Sequence[int], estimator, ranges, fusion_config,
              masks: np.ndarray, timer=None) -> tuple[DecomposedInit, list]:
    """Static cloud once + per-frame moving points with seeded motion (module docstring).

    Returns (the DecomposedInit, the static sweep's V DepthResults).

    scene: the MultiViewVideo (train views only are read); cams: the V posed train cameras;
    frames: init frame indices (F); estimator: a DepthEstimator; ranges: per-view (near, far);
    fusion_config: FusionConfig; masks: (V, F, H, W) bool moving-content masks of those frames.
    timer: optional object with ``add(stage, t0)`` (fixer4d.init.report.Timer).
    """
    frames = [int(f) for f in frames]
    V, F = len(cams), len(frames)
    if masks.shape[:2] != (V, F):
        raise InputError(f"decompose: masks are {masks.shape[:2]}, expected ({V} views, {F} frames)")
    t0 = time.perf_counter()
    imgs = np.stack([[np.asarray(scene.frame(f, c), np.float32) for c in scene.train_ids] for f in frames])  # F,V
    _tick(timer, "load", t0)
    medians, static_res, s_pts, s_cols = _static_cloud(imgs, masks, cams, estimator, ranges, fusion_config, timer)
    scale = scene_scale(s_pts, cams) if len(s_pts) else 1.0

    d_pts, d_cols, d_vis, per_frame = [], [], [], []
    crop_pixels = 0
    for j, f in enumerate(frames):
        pts, cols, vis, views, crop = _frame_moving_points(imgs[j], masks[:, j], cams, estimator, ranges,
                                                           fusion_config, timer)
        d_pts.append(pts)
        d_cols.append(cols)
        d_vis.append(vis)
        crop_pixels += crop
        per_frame.append({"frame": f, "moving_views": views, "moving_points": int(len(pts))})
    d_frames = [np.full(len(p), f, np.int64) for p, f in zip(d_pts, frames)]
    dyn_points = np.concatenate(d_pts).astype(np.float32) if d_pts else np.zeros((0, 3), np.float32)
    dyn_frames = np.concatenate(d_frames) if d_frames else np.zeros(0, np.int64)
    motion, flow_fields = _motion_seeds(scene, frames, cams, d_pts, d_vis, dyn_points, dyn_frames, timer)

    t0 = time.perf_counter()
    colors, visible = sample_view_colors(s_pts.astype(np.float64), medians, static_res, masks.any(axis=1))
    view_std = color_spread(colors, visible) if len(s_pts) else np.zeros(0, np.float32)
    log_gain, gain_stderr, _ = view_gains(colors, visible)
    _tick(timer, "evidence", t0)

    full_pixels = sum(c.width * c.height for c in cams)
    degree = motion["dyn_degree"]
    info = {"static_points": int(len(s_pts)), "moving_points": int(len(dyn_points)),
            "moving_pixel_share": float(masks.mean()), "crop_pixel_share": float(crop_pixels / max(full_pixels * F, 1)),
            "flow_fields": flow_fields, "per_frame": per_frame,
            "tracked_share": float((degree >= 0).mean()) if len(degree) else None}
    return DecomposedInit(
        frames=np.asarray(frames, np.int64), times=np.asarray([scene.time(f) for f in frames], np.float64),
        static_points=s_pts.astype(np.float32), static_colors=s_cols.astype(np.float32), static_view_std=view_std,
        view_log_gain=log_gain.astype(np.float32), view_gain_stderr=gain_stderr.astype(np.float32),
        dyn_points=dyn_points,
        dyn_colors=(np.concatenate(d_cols) if d_cols else np.zeros((0, 3))).astype(np.float32),
        dyn_times=np.asarray([scene.time(int(f)) for f in dyn_frames], np.float64),
        dyn_frames=dyn_frames, **motion, scene_scale=float(scale), info=info), static_res


def _moving_masks(scene, frames: list[int], timer) -> np.ndarray:
    """(V, F, H, W) bool moving-content masks of the init frames (fixer4d.init.masks)."""
    t0 = time.perf_counter()  # decode the frames the masks' statistics read (loading, not preparation)
    for f in statistics_frames(scene.num_frames, frames):
        for c in scene.train_ids:
            scene.frame(f, c)
    timer.add("load", t0)
    t0 = time.perf_counter()
    masks = moving_masks_for_scene(scene, scene.train_ids, frames)
    timer.add("masks", t0)
    return masks


def _decomposed_quality(scene, frames: list[int], masks: np.ndarray, static_res: list, clouds: list[FrameCloud],
                        per_frame: list[dict]) -> dict[str, Any]:
    """The report's ``quality``: each frame's cloud against its true surface (added to
    ``per_frame``), pooled, and the static sweep against the middle init frame's true depth with
    that frame's moving pixels left out."""
    for p, c in zip(per_frame, clouds):
        p.update(Q.frame_cloud_quality(scene, c.frame, c.points))
    quality = Q.summarize_clouds(per_frame)
    j = len(frames) // 2
    moving = [resize_mask(masks[v, j], r.depth.shape) for v, r in enumerate(static_res)]
    quality.update(Q.summarize_depth(Q.frame_depth_quality(scene, frames[j], static_res, moving)))
    return quality


def run_decomposed(scene, cams: Sequence[Camera], frames: list[int], estimator, ranges, config, out_dir: Path,
                   report: dict[str, Any], timer, t_start: float, want_quality: bool, progress: bool
                   ) -> tuple[list[FrameCloud], dict[str, Any]]:
    """``run_init``'s MVS path with decomposition: masks -> ``decompose`` -> files + report.

    Writes ``masks.npz``, ``decomposed.npz``, ``frame_XXXX.ply`` (static + that frame's moving
    points) and ``init_report.json`` (with a ``decomposition`` section). Returns (the per-frame
    clouds, report) like ``run_init``.
    """
    out_dir = Path(out_dir)
    masks = _moving_masks(scene, frames, timer)
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
        report["quality"] = _decomposed_quality(scene, frames, masks, static_res, clouds, per_frame)
        timer.add("quality", t0)
    report["points_per_frame"] = [len(c) for c in clouds]
    report["per_frame"] = per_frame
    report["decomposition"] = {k: v for k, v in dec.info.items() if k != "per_frame"}
    finish_report(report, timer, t_start, config, estimator, out_dir)
    return clouds, report
