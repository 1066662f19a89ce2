"""Self-calibration of a static synchronized rig from its own frames (structure from motion).

The rig does not move and its cameras are synchronized, so every camera has one pose and one
set of intrinsics for the whole clip, while the scene in front of it changes. Matches are pooled
over time: at each of T timestamps spread over the clip, the features of every camera pair (SIFT,
or XFeat + LighterGlue for wide baselines: ``fixer4d.calib.matchers``) are matched at that same instant (moving content matches too: at one instant it obeys the
same epipolar geometry as the background). Each camera is one COLMAP image whose keypoints are
the union of its T frames' keypoints; the pooled matches of a pair are verified together (one
fundamental/essential matrix) and COLMAP's incremental mapper registers the V images (one lens
model shared while mapping, or the focal priors held). A last bundle adjustment
(``fixer4d.calib.adjust``) refines every camera's own focal with the focal priors the
frames allow (``fixer4d.calib.priors``) and gives each camera's standard errors, which the gate
reads. The result is normalised to the rig: origin at the mean camera centre, unit = rig radius
(the largest centre distance from that mean); orientation as COLMAP left it (its first registered
camera's axes).
"""
from __future__ import annotations

import shutil
import tempfile
import time
from dataclasses import dataclass, field
from itertools import combinations
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from tqdm import tqdm

from fixer4d.calib.adjust import CameraState, Observations, repeat_weights
from fixer4d.calib.colmap import pycolmap_module, quiet, rig_camera_from_colmap
from fixer4d.calib.matchers import MATCHERS, make_matcher
from fixer4d.calib.priors import FocalPrior, weigh_priors
from fixer4d.calib.rig import Rig, RigCamera
from fixer4d.errors import InputError

if TYPE_CHECKING:  # calib reads a capture's frames through the object it is given; scene imports calib
    from fixer4d.scene.capture import CaptureFiles

# Timestamps pooled per camera pair: 12 spread frames give a 4-camera rig several thousand
# matches per overlapping pair while SIFT over all 48 frames stays a few seconds at 640x360.
SFM_TIMESTAMPS = 12
# SIFT features per frame (OpenCV keeps the strongest).
SFM_MAX_FEATURES = 4000
# Lowe's ratio test; 0.8 is COLMAP's default for SIFT.
SFM_RATIO = 0.8
# Initial focal guess before bundle adjustment, as a multiple of the larger image side (COLMAP's default).
FOCAL_GUESS = 1.2
# COLMAP's lens model for self-calibration: one focal, the image centre, no distortion. One pose
# per camera for the whole clip is a handful of views: a principal point trades against the
# camera's rotation, a radial term against its focal (freed, k1 moved Panoptic's four focals by
# +3 to +5 % and bent the parallel demo grid's rotations by 1.5 degrees). A lens that does distort
# shows as reprojection error, which the gate bounds.
SFM_CAMERA_MODEL = "SIMPLE_PINHOLE"
SCALE_SFM = "rig radius = 1 (structure from motion fixes no metric unit): origin at the mean camera centre"
COLMAP_SEED = 0


@dataclass
class SfMConfig:
    """timestamps: frames pooled per camera. max_features: keypoints per frame. ratio: SIFT's
    ratio test. matcher: ``matchers.MATCHERS``. focal: priors per camera name
    (``fixer4d.calib.priors``); cameras without one have their focal estimated."""

    timestamps: int = SFM_TIMESTAMPS
    max_features: int = SFM_MAX_FEATURES
    ratio: float = SFM_RATIO
    matcher: str = "sift"
    focal: dict[str, FocalPrior] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.matcher not in MATCHERS:
            raise InputError(f"--matcher {self.matcher!r}: use one of {', '.join(MATCHERS)}")
        if self.timestamps < 1:
            raise InputError(f"--timestamps {self.timestamps}: must be >= 1")


def spread_frames(num_frames: int, count: int) -> list[int]:
    """``count`` frame numbers spread evenly over [0, num_frames)."""
    return sorted({int(round(v)) for v in np.linspace(0, num_frames - 1, min(count, num_frames))})


@dataclass
class PooledMatches:
    """keypoints[c]: (N_c, 2) of camera c over all frames; matches[(a, b)]: (M, 2) indices into them."""

    keypoints: list[np.ndarray]
    matches: dict[tuple[int, int], np.ndarray]
    frames: list[int]


def pool_matches(files: CaptureFiles, config: SfMConfig, progress: bool = True) -> PooledMatches:
    """Features of every camera at the spread frames, matched per pair at the same instant
    (``config.matcher``, ``fixer4d.calib.matchers``)."""
    matcher = make_matcher(config.matcher, config.max_features, config.ratio)
    frames = spread_frames(files.num_frames, config.timestamps)
    V = len(files.sources)
    keypoints: list[list[np.ndarray]] = [[] for _ in range(V)]
    offsets = np.zeros((V, len(frames)), np.int64)
    matches: dict[tuple[int, int], list[np.ndarray]] = {p: [] for p in combinations(range(V), 2)}
    bar = tqdm(total=len(frames), desc="calibrate: features and matches", unit="frame", disable=not progress)
    for t, f in enumerate(frames):
        feats = []
        for c in range(V):
            xy, desc = matcher.features(files.frame(f, c))
            offsets[c, t] = sum(len(k) for k in keypoints[c])
            keypoints[c].append(xy)
            feats.append(desc)
        for a, b in matches:
            m = matcher.match(feats[a], feats[b])
            matches[(a, b)].append(m + [offsets[a, t], offsets[b, t]])
        bar.update(1)
    bar.close()
    return PooledMatches([np.concatenate(k) if k else np.zeros((0, 2), np.float32) for k in keypoints],
                         {p: np.concatenate(m) if m else np.zeros((0, 2), np.int64) for p, m in matches.items()}, frames)


def _write_database(pycolmap, db_path: Path, files: CaptureFiles, pooled: PooledMatches, shared: bool,
                    focal: dict[str, FocalPrior]) -> list[int]:
    """A COLMAP database with one image per camera, its pooled keypoints and the raw matches;
    returns the image ids in camera order."""
    image_ids = []
    with pycolmap.Database.open(str(db_path)) as db:
        camera_id = None
        for c, src in enumerate(files.sources):
            if camera_id is None or not shared:
                prior = focal.get(src.name)
                f = prior.focal_px if prior is not None else FOCAL_GUESS * max(src.width, src.height)
                cam = pycolmap.Camera(model=SFM_CAMERA_MODEL, width=src.width, height=src.height,
                                      params=[f, src.width / 2.0, src.height / 2.0])
                cam.has_prior_focal_length = prior is not None
                camera_id = db.write_camera(cam)
                cam.camera_id = camera_id
                rig = pycolmap.Rig()
                rig.add_ref_sensor(cam.sensor_id)
                rig_id = db.write_rig(rig)
            image = pycolmap.Image(name=f"{src.name}.png", camera_id=camera_id)
            image_id = db.write_image(image)
            image.image_id = image_id
            frame = pycolmap.Frame()
            frame.rig_id = rig_id
            frame.add_data_id(image.data_id)
            db.write_frame(frame)
            db.write_keypoints(image_id, pooled.keypoints[c].astype(np.float32))
            image_ids.append(image_id)
        for (a, b), m in pooled.matches.items():
            if len(m):
                db.write_matches(image_ids[a], image_ids[b], m.astype(np.uint32))
    return image_ids


def _shared_points(rec, image_ids: list[int]) -> dict[tuple[int, int], int]:
    """The 3D points each pair of cameras (indices into ``image_ids``) shares."""
    index = {iid: k for k, iid in enumerate(image_ids)}
    shared: dict[tuple[int, int], int] = {}
    for p in rec.points3D.values():
        ks = sorted({index[e.image_id] for e in p.track.elements if e.image_id in index})
        for pair in combinations(ks, 2):
            shared[pair] = shared.get(pair, 0) + 1
    return shared


def _pose(image) -> np.ndarray:
    """(4, 4) world-to-camera of a registered pycolmap image."""
    cfw = image.cam_from_world
    cfw = cfw() if callable(cfw) else cfw
    w2c = np.eye(4)
    w2c[:3] = np.asarray(cfw.matrix(), np.float64)
    return w2c


def _observations(rec, image_ids: list[int]) -> tuple[Observations, CameraState]:
    """COLMAP's registered cameras (in ``image_ids`` order) and their observed points, moved to
    the rig's frame: origin at the mean camera centre, unit = rig radius."""
    cams = [rig_camera_from_colmap(rec.cameras[rec.images[i].camera_id], str(i), _pose(rec.images[i]), "SfM")
            for i in image_ids]
    centres = np.stack([np.linalg.inv(c.w2c)[:3, 3] for c in cams])
    mean = centres.mean(0)
    radius = max(float(np.max(np.linalg.norm(centres - mean, axis=1))), 1e-12)
    point_ids = sorted(rec.points3D)
    row = {pid: k for k, pid in enumerate(point_ids)}
    cam, point, xy = [], [], []
    for k, iid in enumerate(image_ids):
        for p in rec.images[iid].points2D:
            if p.has_point3D():
                cam.append(k)
                point.append(row[p.point3D_id])
                xy.append(np.asarray(p.xy, np.float64))
    points = (np.array([rec.points3D[pid].xyz for pid in point_ids], np.float64).reshape(-1, 3) - mean) / radius
    state = CameraState(np.stack([c.w2c[:3, :3] for c in cams]), (centres - mean) / radius,
                        np.array([c.K[0, 0] for c in cams]), np.stack([c.K[:2, 2] for c in cams]))
    cam, xy = np.array(cam), np.array(xy).reshape(-1, 2)
    return Observations(cam, np.array(point), xy, points, repeat_weights(cam, xy)), state


def _normalise(cams: list[RigCamera]) -> list[RigCamera]:
    """Origin at the mean camera centre, unit = rig radius (largest centre distance from it)."""
    centres = np.stack([np.linalg.inv(c.w2c)[:3, 3] for c in cams])
    mean = centres.mean(0)
    radius = max(float(np.max(np.linalg.norm(centres - mean, axis=1))), 1e-12)
    out = []
    for c, centre in zip(cams, centres):
        w2c = c.w2c.copy()
        w2c[:3, 3] = -w2c[:3, :3] @ ((centre - mean) / radius)
        out.append(RigCamera(c.name, c.width, c.height, c.K, w2c, dict(c.distortion), c.reprojection_error_px))
    return out


def calibrate_sfm(files: CaptureFiles, config: SfMConfig | None = None, progress: bool = True) -> Rig:
    """Self-calibrate the rig of ``files``; returns the Rig (unchecked: ``fixer4d.calib.gate`` judges it).

    Cameras COLMAP could not register come back absent from ``rig.cameras``; ``rig.pairs`` holds
    per pair the raw pooled matches, the geometrically verified ones and the 3D points both see;
    ``rig.checks["cameras"]`` per camera its focal, the standard errors of focal (px), rotation
    (degrees) and centre (share of the rig radius), the frames' own focal and the prior's verdict.
    """
    config = config or SfMConfig()
    if len(files.sources) < 2:
        raise InputError(f"{files.root}: calibration needs at least 2 cameras, found {files.names}")
    # one lens model while mapping (more matches per parameter) unless sizes or priors differ;
    # the last adjustment frees every camera's focal
    shared = (len({(s.width, s.height) for s in files.sources}) == 1
              and len({config.focal.get(n) for n in files.names}) == 1)
    t0 = time.perf_counter()
    pycolmap = pycolmap_module()
    pooled = pool_matches(files, config, progress)
    checks: dict = {}
    cams: list[RigCamera] = []
    shared_points: dict[tuple[int, int], int] = {}
    work = Path(tempfile.mkdtemp(prefix="fixer4d_calib_"))
    try:
        db_path = work / "database.db"
        (work / "images").mkdir()
        (work / "sparse").mkdir()
        pycolmap.set_random_seed(COLMAP_SEED)
        with quiet(pycolmap):
            image_ids = _write_database(pycolmap, db_path, files, pooled, shared, config.focal)
            pairs_txt = work / "pairs.txt"
            pairs_txt.write_text("".join(f"{files.names[a]}.png {files.names[b]}.png\n" for a, b in pooled.matches))
            pycolmap.verify_matches(str(db_path), str(pairs_txt))
            verified = {}
            with pycolmap.Database.open(str(db_path)) as db:
                for a, b in pooled.matches:
                    ia, ib = image_ids[a], image_ids[b]
                    verified[(a, b)] = (len(db.read_two_view_geometry(ia, ib).inlier_matches)
                                        if db.exists_two_view_geometry(ia, ib) else 0)
            options = pycolmap.IncrementalPipelineOptions()
            options.min_model_size = 2
            options.multiple_models = False
            options.extract_colors = False
            options.num_threads = 1
            options.random_seed = COLMAP_SEED
            options.ba_refine_focal_length = not config.focal
            options.ba_refine_principal_point = False
            if progress:
                print("[fixer4d] calibrate: incremental mapping and bundle adjustment", flush=True)
            recs = pycolmap.incremental_mapping(str(db_path), str(work / "images"), str(work / "sparse"), options)
        rec = max(recs.values(), key=lambda r: (r.num_reg_images(), r.num_points3D())) if recs else None
        if rec is not None:
            shared_points = _shared_points(rec, image_ids)
            registered = [c for c, i in enumerate(image_ids) if i in rec.images and rec.images[i].has_pose]
            if len(registered) >= 2:
                cams = _adjusted_cameras(rec, files, [image_ids[c] for c in registered], registered, config, checks)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    pairs = [{"cameras": [files.names[a], files.names[b]], "raw_matches": int(len(pooled.matches[(a, b)])),
              "verified_matches": int(verified[(a, b)]), "shared_points": int(shared_points.get((a, b), 0))}
             for a, b in pooled.matches]
    given = f"focal priors for {sorted(config.focal)}" if config.focal else "focals estimated"
    rig = Rig(cams, pairs, [files.start + f for f in pooled.frames], SCALE_SFM,
              f"structure from motion over {len(pooled.frames)} timestamps ({config.matcher} matches, "
              f"{SFM_CAMERA_MODEL} per camera, {given})",
              checks)
    rig.checks["seconds"] = round(time.perf_counter() - t0, 2)
    return rig


def _adjusted_cameras(rec, files: CaptureFiles, image_ids: list[int], registered: list[int], config: SfMConfig,
                      checks: dict) -> list[RigCamera]:
    """The registered cameras after the last bundle adjustment (``priors.weigh_priors``); fills
    ``checks["cameras"]`` with each one's figures and the residual's standard deviation."""
    from fixer4d.calib.gate import MAX_FOCAL_SD_REL

    names = [files.names[c] for c in registered]
    obs, state = _observations(rec, image_ids)
    final, free, verdicts = weigh_priors(obs, state, names, config.focal, MAX_FOCAL_SD_REL)
    checks["reprojection_sd_px"] = round(final.sigma_px, 4)
    checks["cameras"] = {}
    cams = []
    for k, (c, name) in enumerate(zip(registered, names)):
        src = files.sources[c]
        f = float(final.cameras.f[k])
        K = np.array([[f, 0.0, final.cameras.c[k, 0]], [0.0, f, final.cameras.c[k, 1]], [0.0, 0.0, 1.0]])
        w2c = np.eye(4)
        w2c[:3, :3] = final.cameras.R[k]
        w2c[:3, 3] = -final.cameras.R[k] @ final.cameras.C[k]
        cams.append(RigCamera(name, src.width, src.height, K, w2c, {},
                              float(final.mean_error_px[k])))
        prior = config.focal.get(name)
        checks["cameras"][name] = {
            "focal_px": round(f, 2), "focal_sd_px": round(float(final.focal_sd_px[k]), 3),
            "rotation_sd_deg": round(float(final.rotation_sd_deg[k]), 4),
            "centre_sd_rel": round(float(final.centre_sd[k]), 5),
            "frames_focal_px": round(float(free.cameras.f[k]), 2),
            "frames_focal_sd_px": round(float(free.focal_sd_px[k]), 3),
            "prior": None if prior is None else {"focal_px": prior.focal_px, "sd_px": prior.sd_px,
                                                 "verdict": verdicts[name]}}
    return _normalise(cams)
