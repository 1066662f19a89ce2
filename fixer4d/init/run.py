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
from fixer4d.init.cloud import FrameCloud, save_frame_clouds
from fixer4d.init.constants import QUALITY_COMPLETENESS_REL
from fixer4d.init.fusion import FusionConfig
from fixer4d.init.mvs import MVSAnywhereConfig, PlaneSweepConfig
from fixer4d.init.poses import PoseConfig
from fixer4d.init.report import REPORT_NAME, Timer, finish_report, gt_depth_at  # noqa: F401 (REPORT_NAME re-exported)
from fixer4d.init.sparse import SparseConfig

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
    return [np.asarray(scene.frame(frame, i), np.float32) for i in scene.train_ids]


def _resolve_frames(scene, frames: list[int] | None) -> list[int]:
    if frames is None:
        return list(range(scene.num_frames))
    frames = [int(f) for f in frames]
    if not frames:
        raise InputError("init: empty frame list; pass frames like --frames 0:4")
    bad = [f for f in frames if not 0 <= f < scene.num_frames]
    if bad:
        raise InputError(f"init: frames {bad} outside [0, {scene.num_frames}) of scene {scene.name}")
    return frames


def run_init(scene, method: str, out_dir: str | Path, frames: list[int] | None = None,
             config: InitConfig | None = None, progress: bool = True) -> tuple[list[FrameCloud], dict]:
    """Initialize per-frame point clouds of ``scene`` (a MultiViewVideo) from its train views.

    method: "sparse" (COLMAP triangulation with fixed poses) or "mvs" (depth estimator + fusion).
    frames: frame indices (default: all). Writes ``out_dir/frame_XXXX.ply`` per frame and
    ``out_dir/init_report.json``; returns (clouds, report).
    """
    from fixer4d.init import quality as Q
    from fixer4d.init.fusion import fuse_results
    from fixer4d.init.mvs import make_estimator, scene_depth_ranges
    from fixer4d.init.poses import align_cameras, compare_poses, estimate_poses
    from fixer4d.init.sparse import sparse_cloud

    if method not in METHODS:
        raise InputError(f"init: unknown method {method!r}; choose one of {list(METHODS)}")
    config = config or InitConfig()
    if config.poses.source not in ("given", "sfm"):
        raise InputError(f"init: pose source {config.poses.source!r}; choose 'given' or 'sfm'")
    if len(scene.train_ids) < 2:
        raise InputError(f"init: scene {scene.name} has {len(scene.train_ids)} train camera(s); need at least 2")
    frames = _resolve_frames(scene, frames)
    out_dir = Path(out_dir)
    t_start = time.perf_counter()
    timer = Timer()
    given = scene.train_cameras
    report: dict[str, Any] = {"method": method, "frames": frames, "points_per_frame": [], "seconds": {},
                              "quality": None, "scene": scene.name, "pose_source": config.poses.source,
                              "pose_error": None}

    # -- poses --------------------------------------------------------------------------------
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
                # express the SfM frame in the scene's frame so that held-out cameras still line up
                sim = align_cameras(sfm.cameras, given)
                cams = [sim.apply_camera(c) for c in sfm.cameras]
                sfm_points = sim.apply_points(sfm.points)
        timer.add("poses", t0)

    # -- per frame ----------------------------------------------------------------------------
    estimator = None
    ranges = None
    if method == "mvs":
        t0 = time.perf_counter()
        estimator = make_estimator(config.estimator, config.mvs, config.mvsanywhere)
        # SfM points, else the train cameras' common view; never scene ground truth.
        ranges, report["depth_range_source"] = scene_depth_ranges(cams, sfm_points)
        report["depth_ranges"] = [list(r) for r in ranges]
        timer.add("depth_range", t0)

    want_quality = config.quality and scene.has_depth
    if method == "mvs" and config.decompose:
        from fixer4d.init.decompose import run_decomposed

        return run_decomposed(scene, cams, frames, estimator, ranges, config, out_dir, report, timer, t_start,
                              want_quality, progress)
    clouds: list[FrameCloud] = []
    per_frame: list[dict] = []
    depth_stats: list[dict] = []
    iterator = frames
    if progress:
        from tqdm import tqdm

        iterator = tqdm(frames, desc=f"init {method}", unit="frame")
    for f in iterator:
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
        clouds.append(cloud)
        info["points"] = len(cloud)
        if want_quality:
            t0 = time.perf_counter()
            all_ids = list(scene.train_ids) + [i for i in scene.test_ids if i not in scene.train_ids]
            surface, scale = Q.surface_samples([scene.depth(f, i) for i in all_ids], [scene.cameras[i] for i in all_ids])
            info.update(Q.cloud_quality(cloud.points, surface, scale))
            if results is not None:
                st = [Q.depth_quality(r.depth, r.valid, gt_depth_at(scene, i, f, r.camera))
                      for r, i in zip(results, scene.train_ids)]
                depth_stats.extend(st)
                info.update(Q.summarize_depth(st))
            timer.add("quality", t0)
        per_frame.append(info)

    t0 = time.perf_counter()
    save_frame_clouds(out_dir, clouds)
    timer.add("write", t0)

    report["points_per_frame"] = [len(c) for c in clouds]
    if want_quality:
        acc = [p["accuracy"] for p in per_frame if p.get("accuracy") is not None]
        quality = {"accuracy": float(np.mean(acc)) if acc else None,
                   "accuracy_rel": float(np.mean([p["accuracy_rel"] for p in per_frame if p.get("accuracy_rel") is not None]))
                   if acc else None,
                   "completeness": float(np.mean([p["completeness"] for p in per_frame])),
                   "completeness_tolerance_rel": QUALITY_COMPLETENESS_REL,
                   "depth_abs_rel": None}
        if depth_stats:
            quality.update(Q.summarize_depth(depth_stats))
        report["quality"] = quality
    report["per_frame"] = per_frame
    finish_report(report, timer, t_start, config, estimator, out_dir)
    return clouds, report


# Stages whose time counts as preparing the init (loading, writing and quality checks do not;
# a pose *check* with given poses is a diagnostic, not part of preparing the clouds).
