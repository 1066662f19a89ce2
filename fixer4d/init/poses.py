"""Camera poses: pycolmap SfM on the train views of one timestamp, and its error vs given poses.

The rig is fixed, so the poses found at t = 0 hold for every frame. Intrinsics are taken as
known (every loader provides them) and kept fixed in bundle adjustment; SfM only recovers the
poses, up to a similarity. ``compare_poses`` aligns the estimate to the given poses with a
similarity (Umeyama on the centres) and reports rotation error (degrees) and centre error
relative to the rig radius.

``ColmapWorkspace`` is the shared pycolmap plumbing (images on disk, SIFT, exhaustive matching)
that the sparse baseline reuses for each frame; it lives in a temporary folder removed on exit.
"""
from __future__ import annotations

import shutil
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from fixer4d.calib.colmap import pycolmap_module as _pycolmap
from fixer4d.calib.colmap import quiet as quiet_colmap
from fixer4d.errors import InputError
from fixer4d.geometry.camera import Camera, rig_extent
import fixer4d.init.constants as C

POSE_ADVICE = ("supply poses instead: load the scene from a layout that carries them (Panoptic train_meta.json, "
               "Neural3DV poses_bounds.npy, a synthetic spec) and use `--poses given` (the default)")


@dataclass
class PoseConfig:
    """SfM settings. source: "given" (use the scene's poses) or "sfm" (estimate them).
    check: with given poses, also run SfM and report its error against them.
    max_features: SIFT features per image. num_threads: pycolmap threads (-1 = all cores: faster, not reproducible;
    see constants.COLMAP_THREADS)."""

    source: str = "given"
    check: bool = False
    max_features: int = C.SIFT_MAX_FEATURES
    num_threads: int = C.COLMAP_THREADS


@dataclass
class SfMResult:
    """cameras: the input cameras with estimated c2w (SfM frame). points (N,3) / colors (N,3)
    in [0,1]: the SfM points. seconds: wall time of the whole estimation."""

    cameras: list[Camera]
    points: np.ndarray
    colors: np.ndarray
    seconds: float
    stats: dict = field(default_factory=dict)


def cam_from_world_matrix(image) -> np.ndarray:
    """(3, 4) world-to-camera of a pycolmap Image (a method in pycolmap >= 3.12, a field before)."""
    cfw = image.cam_from_world
    cfw = cfw() if callable(cfw) else cfw
    return np.asarray(cfw.matrix(), dtype=np.float64)


class ColmapWorkspace:
    """A temporary COLMAP project for V images of one timestamp: images written as PNG,
    one PINHOLE camera per image with the known intrinsics, SIFT features, exhaustive matching.

    Use as a context manager; the folder is deleted on exit.
    """

    def __init__(self, images: list[np.ndarray], cameras: list[Camera], *, max_features: int = C.SIFT_MAX_FEATURES,
                 num_threads: int = C.COLMAP_THREADS, root: str | Path | None = None) -> None:
        if len(images) != len(cameras):
            raise InputError(f"{len(images)} images but {len(cameras)} cameras; pass one camera per image")
        if len(images) < 2:
            raise InputError(f"COLMAP needs at least 2 views, got {len(images)}")
        for img, cam in zip(images, cameras):
            if np.asarray(img).shape[:2] != (cam.height, cam.width):
                raise InputError(f"image of camera {cam.name!r} is {np.asarray(img).shape[:2]}, camera says "
                                 f"{cam.height}x{cam.width}; resize the image or use Camera.resized")
        self.images = images
        self.cameras = cameras
        self.max_features = int(max_features)
        self.num_threads = int(num_threads)
        self._root = root
        self.dir: Path | None = None
        self.names = [f"{i:03d}.png" for i in range(len(images))]

    def __enter__(self) -> "ColmapWorkspace":
        self.dir = Path(tempfile.mkdtemp(prefix="fixer4d_colmap_", dir=self._root))
        self.image_dir.mkdir()
        _pycolmap().set_random_seed(C.COLMAP_SEED)
        return self

    def __exit__(self, *exc) -> None:
        if self.dir is not None:
            shutil.rmtree(self.dir, ignore_errors=True)

    @property
    def image_dir(self) -> Path:
        return self.dir / "images"

    @property
    def database(self) -> Path:
        return self.dir / "database.db"

    def extract_and_match(self) -> dict:
        """SIFT on every image (known PINHOLE intrinsics) + exhaustive matching with geometric
        verification. Returns counts: keypoints per image, verified pairs, inlier matches."""
        from PIL import Image

        pycolmap = _pycolmap()
        with quiet_colmap(pycolmap):
            for name, img, cam in zip(self.names, self.images, self.cameras):
                rgb8 = np.round(np.clip(np.nan_to_num(np.asarray(img, np.float32)), 0, 1) * 255).astype(np.uint8)
                Image.fromarray(rgb8).save(self.image_dir / name)
                reader = pycolmap.ImageReaderOptions()
                reader.camera_model = "PINHOLE"
                reader.camera_params = f"{cam.fx!r},{cam.fy!r},{cam.cx!r},{cam.cy!r}"
                extraction = pycolmap.FeatureExtractionOptions()
                extraction.num_threads = self.num_threads
                extraction.sift.max_num_features = self.max_features
                pycolmap.extract_features(self.database, self.image_dir, image_names=[name],
                                          camera_mode=pycolmap.CameraMode.PER_IMAGE, reader_options=reader,
                                          extraction_options=extraction, device=pycolmap.Device.cpu)
            matching = pycolmap.FeatureMatchingOptions()
            matching.num_threads = self.num_threads
            pycolmap.match_exhaustive(self.database, matching_options=matching, device=pycolmap.Device.cpu)
            with pycolmap.Database.open(self.database) as db:
                ids = {im.name: im.image_id for im in db.read_all_images()}
                stats = {"keypoints": [int(db.num_keypoints_for_image(ids[n])) for n in self.names],
                         "verified_pairs": int(db.num_verified_image_pairs()),
                         "inlier_matches": int(db.num_inlier_matches())}
        return stats

    def fixed_pose_reconstruction(self):
        """A pycolmap Reconstruction holding every image with its given pose (no points)."""
        pycolmap = _pycolmap()
        rec = pycolmap.Reconstruction()
        with pycolmap.Database.open(self.database) as db:
            for cam in db.read_all_cameras():
                rec.add_camera_with_trivial_rig(cam)
            for im in db.read_all_images():
                cam = self.cameras[self.names.index(im.name)]
                image = pycolmap.Image(name=im.name, camera_id=im.camera_id, image_id=im.image_id)
                rec.add_image_with_trivial_frame(image, pycolmap.Rigid3d(cam.w2c[:3]))
        return rec

    def triangulate(self) -> tuple[np.ndarray, np.ndarray]:
        """Triangulate the matches with the fixed poses -> (points (N,3), colors (N,3) in [0,1])."""
        pycolmap = _pycolmap()
        out = self.dir / "triangulated"
        out.mkdir()
        with quiet_colmap(pycolmap):
            rec = pycolmap.triangulate_points(self.fixed_pose_reconstruction(), self.database, self.image_dir, out)
        return _points_of(rec)

    def map(self) -> "object":
        """Incremental mapping with the intrinsics held fixed -> the largest pycolmap Reconstruction,
        or None when nothing registered."""
        pycolmap = _pycolmap()
        out = self.dir / "sparse"
        out.mkdir()
        options = pycolmap.IncrementalPipelineOptions()
        options.num_threads = self.num_threads
        options.ba_refine_focal_length = False
        options.ba_refine_principal_point = False
        options.ba_refine_extra_params = False
        options.random_seed = 0
        with quiet_colmap(pycolmap):
            recs = pycolmap.incremental_mapping(self.database, self.image_dir, out, options)
        if not recs:
            return None
        return max(recs.values(), key=lambda r: (r.num_reg_images(), r.num_points3D()))


def _points_of(rec) -> tuple[np.ndarray, np.ndarray]:
    pts = list(rec.points3D.values())
    if not pts:
        return np.zeros((0, 3), np.float32), np.zeros((0, 3), np.float32)
    xyz = np.array([p.xyz for p in pts], dtype=np.float64)
    rgb = np.array([p.color for p in pts], dtype=np.float32) / 255.0
    ok = np.all(np.isfinite(xyz), 1)
    return xyz[ok].astype(np.float32), rgb[ok]


def estimate_poses(images: list[np.ndarray], cameras: list[Camera], config: PoseConfig | None = None) -> SfMResult:
    """SfM on V synchronized views: SIFT, exhaustive matching, incremental mapping (CPU).

    images: V (H, W, 3) float32 RGB. cameras: V cameras giving intrinsics, size and name (their
    poses are ignored). Returns the cameras with estimated poses in the SfM frame (arbitrary
    similarity) and the SfM points. Raises InputError when matching finds too little or not
    every view registers, with advice on supplying poses.
    """
    config = config or PoseConfig()
    t0 = time.perf_counter()
    with ColmapWorkspace(images, cameras, max_features=config.max_features, num_threads=config.num_threads) as ws:
        stats = ws.extract_and_match()
        if stats["inlier_matches"] < C.SFM_MIN_INLIER_MATCHES:
            raise InputError(f"SfM: only {stats['inlier_matches']} verified SIFT matches between the {len(images)} views "
                             f"(keypoints per view {stats['keypoints']}; need >= {C.SFM_MIN_INLIER_MATCHES}): the views "
                             f"are textureless or do not overlap; {POSE_ADVICE}")
        rec = ws.map()
        registered = {} if rec is None else {im.name: im for im in rec.images.values() if im.has_pose}
        missing = [cameras[i].name or str(i) for i, n in enumerate(ws.names) if n not in registered]
        n_points = 0 if rec is None else rec.num_points3D()
        if missing or n_points < C.SFM_MIN_POINTS:
            raise InputError(f"SfM registration failed: views {missing or 'all'} registered with {n_points} points "
                             f"(need every view and >= {C.SFM_MIN_POINTS} points); {POSE_ADVICE}")
        estimated = []
        for name, cam in zip(ws.names, cameras):
            w2c = np.eye(4)
            w2c[:3] = cam_from_world_matrix(registered[name])
            estimated.append(cam.with_pose(np.linalg.inv(w2c)))
        points, colors = _points_of(rec)
    stats["points"] = int(points.shape[0])
    return SfMResult(estimated, points, colors, time.perf_counter() - t0, stats)


# ---- similarity alignment and pose error ----------------------------------------------------
@dataclass
class Similarity:
    """x -> scale * R x + t (world units of the target)."""

    scale: float
    R: np.ndarray
    t: np.ndarray

    def apply_points(self, points: np.ndarray) -> np.ndarray:
        return self.scale * np.asarray(points, np.float64) @ self.R.T + self.t

    def apply_camera(self, camera: Camera) -> Camera:
        """The same camera moved into the target frame (rotation and centre; scale moves the centre)."""
        c2w = np.eye(4)
        c2w[:3, :3] = self.R @ camera.R
        c2w[:3, 3] = self.apply_points(camera.center[None])[0]
        return camera.with_pose(c2w)


def umeyama(src: np.ndarray, dst: np.ndarray) -> Similarity:
    """Least-squares similarity with dst ~ scale * R src + t (Umeyama 1991), (N, 3) each, N >= 3
    non-collinear points. Raises InputError for a degenerate configuration."""
    src = np.asarray(src, np.float64)
    dst = np.asarray(dst, np.float64)
    mu_s, mu_d = src.mean(0), dst.mean(0)
    xs, xd = src - mu_s, dst - mu_d
    var_s = float(np.mean(np.sum(xs * xs, 1)))
    if var_s < C.ALIGN_MIN_SPREAD ** 2:
        raise InputError("pose alignment: the estimated camera centres coincide; cannot fit a similarity")
    cov = xd.T @ xs / src.shape[0]
    U, D, Vt = np.linalg.svd(cov)
    S = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        S[2, 2] = -1.0
    R = U @ S @ Vt
    scale = float(np.trace(np.diag(D) @ S) / var_s)
    return Similarity(scale, R, mu_d - scale * R @ mu_s)


def _rotation_mean(rotations: list[np.ndarray]) -> np.ndarray:
    """Chordal L2 mean of rotation matrices (projection of their sum onto SO(3))."""
    U, _, Vt = np.linalg.svd(np.sum(rotations, 0))
    S = np.eye(3)
    S[2, 2] = np.sign(np.linalg.det(U @ Vt))
    return U @ S @ Vt


def align_cameras(estimated: list[Camera], given: list[Camera]) -> Similarity:
    """Similarity from the estimated frame to the given one: Umeyama on the camera centres when
    they span a plane; for (nearly) collinear rigs the rotation comes from the cameras'
    orientations instead (the centres leave the roll about the baseline undetermined)."""
    if len(estimated) != len(given) or len(given) < 2:
        raise InputError(f"pose comparison needs the same cameras on both sides (>= 2), got {len(estimated)} and {len(given)}")
    ce = np.stack([c.center for c in estimated])
    cg = np.stack([c.center for c in given])
    sv = np.linalg.svd(cg - cg.mean(0), compute_uv=False)
    if len(given) >= 3 and sv[1] > 1e-3 * max(sv[0], C.ALIGN_MIN_SPREAD):
        return umeyama(ce, cg)
    R = _rotation_mean([g.R @ e.R.T for e, g in zip(estimated, given)])
    xe, xg = ce - ce.mean(0), cg - cg.mean(0)
    denom = float(np.sum(xe * xe))
    if denom < C.ALIGN_MIN_SPREAD ** 2:
        raise InputError("pose alignment: the estimated camera centres coincide; cannot fit a similarity")
    scale = float(np.sum(xg * (xe @ R.T)) / denom)
    return Similarity(scale, R, cg.mean(0) - scale * R @ ce.mean(0))


def compare_poses(estimated: list[Camera], given: list[Camera]) -> dict:
    """Pose error of ``estimated`` against ``given`` after a similarity alignment.

    Returns rotation_deg_mean/max (angle of R_given^T R_aligned, degrees), center_error_rel_mean/max
    (centre distance / rig radius of the given cameras), scale (of the alignment) and per_camera.
    """
    sim = align_cameras(estimated, given)
    extent = rig_extent(given)
    rot, cen = [], []
    for e, g in zip(estimated, given):
        a = sim.apply_camera(e)
        cos = (np.trace(g.R.T @ a.R) - 1.0) / 2.0
        rot.append(float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))))
        cen.append(float(np.linalg.norm(a.center - g.center) / extent))
    return {"rotation_deg_mean": float(np.mean(rot)), "rotation_deg_max": float(np.max(rot)),
            "center_error_rel_mean": float(np.mean(cen)), "center_error_rel_max": float(np.max(cen)),
            "scale": sim.scale, "rig_radius": extent,
            "per_camera": [{"name": g.name, "rotation_deg": r, "center_error_rel": c}
                           for g, r, c in zip(given, rot, cen)]}
