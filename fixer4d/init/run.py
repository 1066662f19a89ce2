"""run_init: poses -> per-frame clouds (sparse baseline or MVS + fusion) -> PLYs + init_report.json.

Output contract (scripts rely on it), ``out_dir/init_report.json``:
  {"method": "sparse"|"mvs", "frames": [...], "points_per_frame": [...],
   "seconds": {"total": float, ...per stage}, "quality": {"accuracy", "completeness",
   "depth_abs_rel", ...} | null}
plus extra keys (pose error, depth bands, valid share, coverage, per-frame details, config).
"""
from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any, Literal

import numpy as np

from fixer4d.errors import InputError
import fixer4d.init.quality as Q
from fixer4d.init.cloud import FrameCloud, save_frame_clouds
from fixer4d.init.decompose import run_decomposed
from fixer4d.init.depth_range import scene_depth_ranges
from fixer4d.init.fusion import FusionConfig, fuse_results
from fixer4d.init.mvs import make_estimator
from fixer4d.init.mvsanywhere import MVSAnywhereConfig
from fixer4d.init.plane_sweep import PlaneSweepConfig
from fixer4d.init.poses import PoseConfig, align_cameras, compare_poses, estimate_poses
from fixer4d.init.report import Timer, finish_report
from fixer4d.init.sparse import SparseConfig, sparse_cloud

METHODS = ("sparse", "mvs")


@dataclass
class InitConfig:
    """Geometric initialization settings (echoed into runs/<name>/config.json under "init").

    estimator: "planesweep" (built in) or "mvsanywhere" (optional). quality: compare with ground
    truth when the scene has it. Nested: poses, sparse, mvs (plane sweep), mvsanywhere, fusion.
    """

    method: Literal["mvs", "sparse"] = "mvs"
    estimator: str = "planesweep"
    quality: bool = True
    # MVS only: one static cloud for the clip + per-frame moving points from the moving-content
    # masks (fixer4d.init.decompose); False = the per-frame full sweeps of the paper's recipe.
    decompose: bool = True
    poses: PoseConfig = field(default_factory=PoseConfig)
    sparse: SparseConfig = field(default_factory=SparseConfig)
    mvs: PlaneSweepConfig = field(default_factory=PlaneSweepConfig)
    mvsanywhere: MVSAnywhereConfig = field(default_factory=MVSAnywhereConfig)
    fusion: FusionConfig = field(default_factory=FusionConfig)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "InitConfig":
        """Inverse of ``to_dict``; unknown keys raise InputError naming them."""
        nested = {"poses": PoseConfig, "sparse": SparseConfig, "mvs": PlaneSweepConfig,
                  "mvsanywhere": MVSAnywhereConfig, "fusion": FusionConfig}
        kwargs = {}
        names = {f.name for f in fields(cls)}
        for key, value in d.items():
            if key not in names:
                raise InputError(f"init config: unknown key {key!r}; known keys are {sorted(names)}")
            if key in nested:
                sub = nested[key]
                sub_names = {f.name for f in fields(sub)}
                bad = set(value) - sub_names
                if bad:
                    raise InputError(f"init config [{key}]: unknown keys {sorted(bad)}; known keys are {sorted(sub_names)}")
                kwargs[key] = sub(**value)
            else:
                kwargs[key] = value
        return cls(**kwargs)


def _train_images(scene, frame: int) -> list[np.ndarray]:
    """The scene's train views at ``frame``: V (H, W, 3) float32 RGB."""
    return [np.asarray(scene.frame(frame, i), np.float32) for i in scene.train_ids]


def _resolve_frames(scene, frames: list[int] | None) -> list[int]:
    """The init frames: every frame when None, else ``frames`` checked against the scene."""
    if frames is None:
        return list(range(scene.num_frames))
    frames = [int(f) for f in frames]
    if not frames:
        raise InputError("init: empty frame list; pass frames like --frames 0:4")
    bad = [f for f in frames if not 0 <= f < scene.num_frames]
    if bad:
        raise InputError(f"init: frames {bad} outside [0, {scene.num_frames}) of scene {scene.name}")
    return frames


def _check_request(scene, method: str, config: InitConfig) -> None:
    """InputError for an unknown method or pose source, or a scene with fewer than 2 train views."""
    if method not in METHODS:
        raise InputError(f"init: unknown method {method!r}; choose one of {list(METHODS)}")
    if config.poses.source not in ("given", "sfm"):
        raise InputError(f"init: pose source {config.poses.source!r}; choose 'given' or 'sfm'")
    if len(scene.train_ids) < 2:
        raise InputError(f"init: scene {scene.name} has {len(scene.train_ids)} train camera(s); need at least 2")


def _init_poses(scene, config: InitConfig, timer: Timer, report: dict[str, Any]) -> tuple[list, np.ndarray | None]:
    """The train cameras the init uses and the SfM points (None unless SfM gives the poses).

    Poses "given": the scene's own; with ``config.poses.check`` SfM also runs on the train views
    at frame 0 and ``report["pose_error"]`` gets its error (or the failure). Poses "sfm": the SfM
    cameras and points, expressed in the scene's frame so that held-out cameras still line up."""
    given = scene.train_cameras
    cams = given
    sfm_points = None
    if config.poses.source == "sfm" or config.poses.check:
        t0 = time.perf_counter()
        images0 = _train_images(scene, 0)
        timer.add("load", t0)
        t0 = time.perf_counter()
        try:
            sfm = estimate_poses(images0, given, config.poses)
        except InputError as exc:
            if config.poses.source == "sfm":
                raise
            report["pose_error"] = {"error": str(exc)}
        else:
            report["pose_error"] = compare_poses(sfm.cameras, given)
            report["pose_error"].update(sfm_seconds=sfm.seconds, sfm_points=int(sfm.points.shape[0]))
            if config.poses.source == "sfm":
                sim = align_cameras(sfm.cameras, given)
                cams = [sim.apply_camera(c) for c in sfm.cameras]
                sfm_points = sim.apply_points(sfm.points)
        timer.add("poses", t0)
    return cams, sfm_points


def _depth_setup(cams: list, sfm_points: np.ndarray | None, config: InitConfig, timer: Timer,
                 report: dict[str, Any]):
    """The MVS path's depth estimator and per-view (near, far) ranges, from the SfM points, else
    the train cameras' common view; never scene ground truth (their source goes in ``report``)."""
    t0 = time.perf_counter()
    estimator = make_estimator(config.estimator, config.mvs, config.mvsanywhere)
    ranges, report["depth_range_source"] = scene_depth_ranges(cams, sfm_points)
    report["depth_ranges"] = [list(r) for r in ranges]
    timer.add("depth_range", t0)
    return estimator, ranges


def _frame_cloud(scene, f: int, method: str, cams: list, estimator, ranges, config: InitConfig, timer: Timer
                 ) -> tuple[FrameCloud, dict[str, Any], list | None]:
    """One frame's cloud from its train images: the sparse baseline, or MVS + fusion. Returns
    (the cloud, the frame's report entry, the MVS DepthResults or None for sparse)."""
    info: dict[str, Any] = {"frame": f}
    t0 = time.perf_counter()
    images = _train_images(scene, f)
    timer.add("load", t0)
    tf = scene.time(f)
    if method == "sparse":
        t0 = time.perf_counter()
        cloud, st = sparse_cloud(images, cams, f, tf, config.sparse)
        info["seconds"] = timer.add("sparse", t0)
        info.update(keypoints=st["keypoints"], inlier_matches=st["inlier_matches"])
        results = None
    else:
        t0 = time.perf_counter()
        results = estimator.estimate(images, cams, ranges)
        dt_mvs = timer.add("mvs", t0)
        t0 = time.perf_counter()
        pts, cols = fuse_results(images, results, config.fusion)
        dt_fuse = timer.add("fusion", t0)
        cloud = FrameCloud(f, tf, pts, cols)
        info["seconds"] = dt_mvs + dt_fuse
        info["valid_pixels"] = int(sum(r.valid.sum() for r in results))
    info["points"] = len(cloud)
    return cloud, info, results


def _per_frame_clouds(scene, method: str, frames: list[int], cams: list, estimator, ranges, config: InitConfig,
                      timer: Timer, want_quality: bool, progress: bool
                      ) -> tuple[list[FrameCloud], list[dict], list[dict]]:
    """Every frame's own cloud (``_frame_cloud``), with its quality against ground truth when
    ``want_quality``. Returns (clouds, per-frame report entries, per-view depth statistics)."""
    clouds: list[FrameCloud] = []
    per_frame: list[dict] = []
    depth_stats: list[dict] = []
    iterator = frames
    if progress:
        from tqdm import tqdm

        iterator = tqdm(frames, desc=f"init {method}", unit="frame")
    for f in iterator:
        cloud, info, results = _frame_cloud(scene, f, method, cams, estimator, ranges, config, timer)
        clouds.append(cloud)
        if want_quality:
            t0 = time.perf_counter()
            info.update(Q.frame_cloud_quality(scene, f, cloud.points))
            if results is not None:
                st = Q.frame_depth_quality(scene, f, results)
                depth_stats.extend(st)
                info.update(Q.summarize_depth(st))
            timer.add("quality", t0)
        per_frame.append(info)
    return clouds, per_frame, depth_stats


def run_init(scene, method: str, out_dir: str | Path, frames: list[int] | None = None,
             config: InitConfig | None = None, progress: bool = True) -> tuple[list[FrameCloud], dict]:
    """Initialize per-frame point clouds of ``scene`` (a MultiViewVideo) from its train views.

    method: "sparse" (COLMAP triangulation with fixed poses) or "mvs" (depth estimator + fusion).
    frames: frame indices (default: all). Writes ``out_dir/frame_XXXX.ply`` per frame and
    ``out_dir/init_report.json``; returns (clouds, report).
    """
    config = config or InitConfig()
    _check_request(scene, method, config)
    frames = _resolve_frames(scene, frames)
    out_dir = Path(out_dir)
    t_start = time.perf_counter()
    timer = Timer()
    report: dict[str, Any] = {"method": method, "frames": frames, "points_per_frame": [], "seconds": {},
                              "quality": None, "scene": scene.name, "pose_source": config.poses.source,
                              "pose_error": None}
    cams, sfm_points = _init_poses(scene, config, timer, report)
    estimator = ranges = None
    if method == "mvs":
        estimator, ranges = _depth_setup(cams, sfm_points, config, timer, report)
    want_quality = config.quality and scene.has_depth
    if method == "mvs" and config.decompose:
        return run_decomposed(scene, cams, frames, estimator, ranges, config, out_dir, report, timer, t_start,
                              want_quality, progress)
    clouds, per_frame, depth_stats = _per_frame_clouds(scene, method, frames, cams, estimator, ranges, config,
                                                       timer, want_quality, progress)
    t0 = time.perf_counter()
    save_frame_clouds(out_dir, clouds)
    timer.add("write", t0)
    report["points_per_frame"] = [len(c) for c in clouds]
    if want_quality:
        quality = Q.summarize_clouds(per_frame)
        if depth_stats:
            quality.update(Q.summarize_depth(depth_stats))
        report["quality"] = quality
    report["per_frame"] = per_frame
    finish_report(report, timer, t_start, config, estimator, out_dir)
    return clouds, report
