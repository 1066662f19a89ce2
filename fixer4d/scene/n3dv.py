"""The Neural3DV layout: camXX.mp4 per camera + poses_bounds.npy (LLFF), optional scene.json.

poses_bounds.npy (LLFF, ``fixer4d.geometry.llff``) holds one row per camera; rows follow the
sorted camXX.mp4 files unless scene.json lists ``pose_cameras``.

A folder written by ``fixer4d make-scene`` also has scene.json (train/test ids, fps, scene box)
and depth/camXX.npz (ground-truth z-depth, float32 (T, H, W), inf where nothing is hit).
"""
from __future__ import annotations

import re
import threading
from collections import OrderedDict
from pathlib import Path

import numpy as np

from fixer4d.errors import InputError
from fixer4d.geometry.camera import Camera
from fixer4d.geometry.llff import llff_to_cameras, read_poses_bounds
from fixer4d.geometry.rig import centre_camera, most_separated
from fixer4d.jsonfile import read_json_object
from fixer4d.scene.base import FRAME_CACHE_MB, MultiViewVideo, SceneBounds
from fixer4d.scene.video import VideoReader, probe_video

# The Neural3DV sparse-view protocol (4 train views of the 21-camera rig; cam00, the centre
# camera, and all others held out).
N3DV_FULL_RIG = 21
N3DV_DEFAULT_TRAIN = (1, 10, 13, 20)
# A video whose aspect ratio differs from poses_bounds' hwf by more than this is not the same
# camera resized.
ASPECT_RTOL = 0.01
# Ground-truth depth arrays kept in memory (whole camera clips, (T, H, W) float32 each).
DEPTH_CACHE_CAMERAS = 4
_CAM_RE = re.compile(r"^cam(\d+)\.mp4$")


# ---------------------------------------------------------------------------- the scene
class Neural3DVScene(MultiViewVideo):
    """A Neural3DV scene folder, decoded lazily with bounded memory.

    Args:
      root: folder with camXX.mp4 and poses_bounds.npy (and optionally scene.json, depth/).
      scale: image scale (0.5 = half resolution).
      frame_range: (a, b) half-open range of video frames to use.
      train_ids / test_ids: camera ids (XX of camXX). Only the named cameras are loaded when
        either is given; defaults: scene.json's split, else 1,10,13,20 vs. the rest for the full
        21-camera rig, else the 4 most separated cameras (the centre one held out).
    """

    def __init__(self, root: str | Path, scale: float = 1.0, frame_range: tuple[int, int] | None = None,
                 train_ids: list[int] | None = None, test_ids: list[int] | None = None,
                 cache_mb: float = FRAME_CACHE_MB) -> None:
        super().__init__(cache_mb)
        self.root = Path(root)
        self.name = self.root.name
        if scale <= 0 or not np.isfinite(scale):
            raise InputError(f"{self.root}: scale must be > 0, got {scale}")
        meta = self._read_meta()
        videos = _camera_videos(self.root)
        pb_path = self.root / "poses_bounds.npy"
        all_cams, near_far, by_id = _rig_poses(pb_path, meta, videos)
        want = _requested_ids(self.root, videos, train_ids, test_ids)
        self.camera_ids = want
        infos = [probe_video(videos[i]) for i in want]
        self.frame_offset, self.num_frames = _frame_window(self.root, videos, want, infos, frame_range)
        self.fps = float(meta.get("fps", infos[0].fps))
        self.cameras = [_video_camera(all_cams[by_id[i]], inf, videos[i], pb_path, scale)
                        for i, inf in zip(want, infos)]
        self.scale = float(scale)
        self._near_far = near_far[[by_id[i] for i in want]]
        self._videos = [videos[i] for i in want]
        self._readers: dict[int, VideoReader] = {}
        self._readers_lock = threading.Lock()
        self.train_ids, self.test_ids = _split(self.root, meta, want, self.cameras, train_ids, test_ids)
        self._depth_dir = self.root / meta["depth"] if meta.get("depth") else None
        self._depth_cache: OrderedDict[int, np.ndarray] = OrderedDict()
        self._depth_lock = threading.Lock()
        self._meta = meta

    def _read_meta(self) -> dict:
        p = self.root / "scene.json"
        if not p.is_file():
            return {}
        return read_json_object(p, str(p), "fix or delete it")

    def _reader(self, cam: int) -> VideoReader:
        with self._readers_lock:
            if cam not in self._readers:
                self._readers[cam] = VideoReader(self._videos[cam])
            return self._readers[cam]

    def _load_frame(self, frame: int, cam: int) -> np.ndarray:
        img = self._reader(cam).frame(self.frame_offset + frame).astype(np.float32) / 255.0
        c = self.cameras[cam]
        if img.shape[:2] != (c.height, c.width):
            import cv2

            img = cv2.resize(img, (c.width, c.height), interpolation=cv2.INTER_AREA)
        return img

    @property
    def has_depth(self) -> bool:
        return self._depth_dir is not None

    def _load_depth(self, frame: int, cam: int) -> np.ndarray | None:
        if self._depth_dir is None:
            return None
        with self._depth_lock:
            if cam not in self._depth_cache:
                path = self._depth_dir / f"{self.cameras[cam].name}.npz"
                if not path.is_file():
                    raise InputError(f"{path}: ground-truth depth listed in scene.json is missing; "
                                     f"rewrite the scene with `fixer4d make-scene` or remove 'depth' from scene.json")
                with np.load(path, allow_pickle=False) as z:
                    self._depth_cache[cam] = z["depth"]
                while len(self._depth_cache) > DEPTH_CACHE_CAMERAS:
                    self._depth_cache.popitem(last=False)
            arr = self._depth_cache[cam]
        f = self.frame_offset + frame
        if f >= arr.shape[0]:
            raise InputError(f"{self._depth_dir}: depth of {self.cameras[cam].name} has {arr.shape[0]} frames, "
                             f"frame {f} requested; rewrite the scene")
        d = arr[f].astype(np.float32)
        c = self.cameras[cam]
        if d.shape != (c.height, c.width):
            import cv2

            # Nearest neighbour: averaging depths across an occlusion edge invents surfaces.
            d = cv2.resize(d, (c.width, c.height), interpolation=cv2.INTER_NEAREST)
        return d

    def bounds(self) -> SceneBounds:
        """near/far from the train cameras' poses_bounds rows; the box from scene.json, else the
        union of the train cameras' frusta between near and far (loose but safe). Held-out cameras
        never shape the bounds: they feed the random-point fallback of training."""
        rows = self._near_far[list(self.train_ids)]
        near = float(rows[:, 0].min())
        far = float(rows[:, 1].max())
        if "bbox_min" in self._meta and "bbox_max" in self._meta:
            return SceneBounds(near, far, np.asarray(self._meta["bbox_min"], np.float64),
                               np.asarray(self._meta["bbox_max"], np.float64))
        pts = []
        for c in self.train_cameras:
            corners = np.array([[0, 0], [c.width, 0], [0, c.height], [c.width, c.height]], np.float64)
            for z in (near, far):
                pts.append(c.backproject(corners, np.full(4, z)))
        pts = np.concatenate(pts)
        return SceneBounds(near, far, pts.min(0), pts.max(0))


# ---------------------------------------------------------------------------- opening a folder
def _camera_videos(root: Path) -> dict[int, Path]:
    """Camera id -> camXX.mp4 of the folder; InputError when there is none."""
    videos = {int(m.group(1)): root / p.name for p in sorted(root.iterdir()) if (m := _CAM_RE.match(p.name))}
    if not videos:
        raise InputError(f"{root}: no camXX.mp4 videos found; a Neural3DV folder holds cam00.mp4, cam01.mp4, ...")
    return videos


def _rig_poses(pb_path: Path, meta: dict, videos: dict[int, Path]) -> tuple[list[Camera], np.ndarray, dict[int, int]]:
    """(cameras at the hwf resolution, near/far (R, 2), camera id -> row) of poses_bounds.npy,
    whose rows follow scene.json's ``pose_cameras`` or else the sorted video ids; InputError
    when rows and videos do not match up."""
    pb = read_poses_bounds(pb_path)
    row_ids = [int(i) for i in meta.get("pose_cameras", sorted(videos))]
    if pb.ndim == 2 and pb.shape[0] != len(row_ids):
        if "pose_cameras" in meta:
            raise InputError(f"{pb_path}: {pb.shape[0]} rows but scene.json lists {len(row_ids)} pose_cameras; "
                             f"make them agree")
        missing = sorted(videos)[pb.shape[0]:]
        raise InputError(f"{pb_path}: {pb.shape[0]} pose rows for {len(videos)} camera videos, so "
                         f"{', '.join(f'cam{i:02d}.mp4' for i in missing) or 'some rows'} cannot be matched to a pose: "
                         f"add the missing rows (one per camXX.mp4, sorted) or remove the extra videos")
    all_cams, near_far = llff_to_cameras(pb, [f"cam{i:02d}" for i in row_ids], str(pb_path))
    by_id = dict(zip(row_ids, range(len(row_ids))))
    for vid in videos:
        if vid not in by_id:
            raise InputError(f"{videos[vid]}: camera id {vid} is absent from {pb_path} "
                             f"(scene.json pose_cameras = {row_ids}); add its pose or remove the video")
    return all_cams, near_far, by_id


def _requested_ids(root: Path, videos: dict[int, Path], train_ids: list[int] | None,
                   test_ids: list[int] | None) -> list[int]:
    """The camera ids to load, sorted: the named ones when a split is given, else every video."""
    if train_ids is not None or test_ids is not None:
        want = sorted(set(train_ids or []) | set(test_ids or []))
    else:
        want = sorted(videos)
    absent = [i for i in want if i not in videos]
    if absent:
        raise InputError(f"{root}: camera ids {absent} requested but there is no "
                         f"{', '.join(f'cam{i:02d}.mp4' for i in absent)}; available ids: {sorted(videos)}")
    return want


def _frame_window(root: Path, videos: dict[int, Path], want: list[int], infos: list,
                  frame_range: tuple[int, int] | None) -> tuple[int, int]:
    """(first video frame, frame count) of ``frame_range`` (default: all, when the videos of
    ``want`` agree in length); InputError otherwise."""
    counts = [inf.num_frames for inf in infos]
    total = min(counts)
    if frame_range is None:
        if len(set(counts)) > 1:
            short = want[int(np.argmin(counts))]
            raise InputError(f"{videos[short]}: {min(counts)} frames, but other cameras have up to {max(counts)} "
                             f"({dict(zip((f'cam{i:02d}' for i in want), counts))}); trim the videos to the same "
                             f"length or pass frame_range=(a, b) with b <= {min(counts)}")
        frame_range = (0, total)
    a, b = int(frame_range[0]), int(frame_range[1])
    if not 0 <= a < b <= total:
        raise InputError(f"{root}: frame_range {frame_range} must satisfy 0 <= a < b <= {total} "
                         f"(the shortest video's frame count)")
    return a, b - a


def _video_camera(cam: Camera, info, video: Path, pb_path: Path, scale: float) -> Camera:
    """The poses_bounds camera resized to its video's resolution (same aspect ratio within
    ASPECT_RTOL, else InputError), then scaled by ``scale``."""
    if abs(info.width / info.height - cam.width / cam.height) > ASPECT_RTOL * cam.width / cam.height:
        raise InputError(f"{video}: video is {info.width}x{info.height} but {pb_path} says "
                         f"{cam.width}x{cam.height} (different aspect ratio); use the matching poses_bounds.npy")
    if (info.width, info.height) != (cam.width, cam.height):
        cam = cam.resized(info.width, info.height)
    return cam.scaled(scale) if scale != 1.0 else cam


def _split(root: Path, meta: dict, want: list[int], cameras: list[Camera], train_ids: list[int] | None,
           test_ids: list[int] | None) -> tuple[list[int], list[int]]:
    """(train, held-out) indices into the loaded cameras: the arguments, else scene.json's split,
    else 1,10,13,20 vs the rest of the full rig, else the 4 most separated cameras (the centre
    one held out) vs the rest."""
    index_of = {cid: k for k, cid in enumerate(want)}
    if train_ids is not None:
        tr = [int(i) for i in train_ids]
    elif "train_ids" in meta:
        tr = [int(i) for i in meta["train_ids"]]
    elif want == list(range(N3DV_FULL_RIG)):
        tr = list(N3DV_DEFAULT_TRAIN)
    else:
        tr = [want[k] for k in most_separated(cameras, 4, exclude=(centre_camera(cameras),))]
    if test_ids is not None:
        te = [int(i) for i in test_ids]
    elif "test_ids" in meta and train_ids is None:
        te = [int(i) for i in meta["test_ids"]]
    else:
        te = [i for i in want if i not in tr]
    for i in tr + te:
        if i not in index_of:
            raise InputError(f"{root}: camera id {i} (scene.json or arguments) has no loaded camXX.mp4; "
                             f"loaded ids: {want}")
    # a train id listed as held out too: load_scene refuses it (validate.check_ids)
    return [index_of[i] for i in tr], [index_of[i] for i in te]
