"""A capture as people bring it: one video (or one image folder) per camera, any names.

Layout: a folder holding either videos (``*.mp4 *.mov *.mkv *.avi``; camera name = file stem)
or one sub-folder of images per camera (``IMAGE_EXTS``, sorted; camera name = folder
name). Cameras are sorted by name. A folder named ``board`` is never a camera: it holds the
videos of a calibration board (``fixer4d.calib.board``). A calibration beside them is optional
(``fixer4d.calib.formats``): without one the rig is calibrated from the board videos or the
frames (``fixer4d.calib.calibrate_capture``).

``CaptureFiles`` reads the raw frames and checks synchronization: every camera has the same
frame rate, and after the per-camera start offsets (``--offset CAM=N``: the capture's frame f is
frame f + N of that camera) the same number of frames, unless a frame range picks a part all of
them have. ``CaptureScene`` is the scene a run trains on: frames undistorted with the rig's
lens model onto the rig's pinhole cameras; every camera trains unless ``holdout`` names some.
"""
from __future__ import annotations

import threading
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fixer4d.calib.board import BOARD_FOLDER
from fixer4d.calib.rig import Rig, RigCamera, undistort, undistort_maps
from fixer4d.errors import InputError
from fixer4d.scene.base import FRAME_CACHE_MB, MultiViewVideo
from fixer4d.scene.video import VideoReader, probe_video

VIDEO_EXTS = (".mp4", ".mov", ".mkv", ".avi")
# Read by OpenCV as 8-bit colour: 16-bit frames are scaled down, grey ones repeated, alpha dropped.
IMAGE_EXTS = (".jpg", ".jpeg", ".png", ".tif", ".tiff", ".bmp", ".webp")
# Image folders carry no frame rate; playback of the reconstruction uses this one.
IMAGE_FOLDER_FPS = 30.0
# Two cameras whose rates differ by more than this drift apart by a frame within ~1000 frames.
FPS_RTOL = 1e-3


@dataclass(frozen=True)
class CameraSource:
    """One camera's frames: a video file or a sorted list of image files."""

    name: str
    path: Path
    images: tuple[Path, ...] | None  # None for a video
    width: int
    height: int
    num_frames: int
    fps: float | None  # None for an image folder (no rate recorded)


def _image_files(folder: Path) -> list[Path]:
    return sorted(p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_EXTS)


def _videos(root: Path) -> list[Path]:
    return sorted(p for p in root.iterdir() if p.is_file() and p.suffix.lower() in VIDEO_EXTS)


def _image_folders(root: Path) -> list[Path]:
    """The camera image folders of ``root``: not hidden, not the board videos' folder (``BOARD_FOLDER``)."""
    return sorted(p for p in root.iterdir()
                  if p.is_dir() and not p.name.startswith(".") and p.name != BOARD_FOLDER and _image_files(p))


def _folders_without_images(root: Path) -> list[Path]:
    """Sub-folders of ``root`` that look like a camera's image folder with its images missing:
    not hidden, not ``BOARD_FOLDER``, holding files (or nothing) but no sub-folder and no image of
    IMAGE_EXTS. A calibration's own folders (COLMAP's ``sparse/0``) hold sub-folders and are not
    counted."""
    out = []
    for p in sorted(root.iterdir()):
        if not p.is_dir() or p.name.startswith(".") or p.name == BOARD_FOLDER:
            continue
        entries = [e for e in p.iterdir() if not e.name.startswith(".")]
        if not any(e.is_dir() for e in entries) and not _image_files(p):
            out.append(p)
    return out


def _check_one_kind(root: Path, videos: list[Path], folders: list[Path]) -> None:
    """InputError when ``root`` mixes camera videos with image folders, or when an image-folder
    capture has a camera folder without images: either way a camera would silently be left out."""
    if videos and folders:
        raise InputError(f"{root}: holds camera videos ({', '.join(p.name for p in videos)}) and image folders "
                         f"({', '.join(p.name for p in folders)}); a capture is one video per camera or one image "
                         f"folder per camera, not both: move one kind out (a folder becomes a video with e.g. "
                         f"ffmpeg -framerate 30 -pattern_type glob -i 'DIR/*.png' DIR.mp4)")
    if folders:
        empty = _folders_without_images(root)
        if empty:
            found = {p.name: sorted({e.suffix.lower() or e.name for e in p.iterdir() if not e.name.startswith(".")})
                     for p in empty}
            raise InputError(f"{root}: camera folder(s) without images: "
                             + "; ".join(f"{n} (found {v[:4] if v else 'nothing'})" for n, v in found.items())
                             + f"; put each camera's frames there as {', '.join(IMAGE_EXTS)}, or remove the folder")


def is_capture(path: str | Path) -> bool:
    """Whether ``path`` is a folder of camera videos or of per-camera image folders."""
    path = Path(path)
    return path.is_dir() and bool(_videos(path) or _image_folders(path))


def _probe_images(folder: Path) -> CameraSource:
    import cv2

    files = _image_files(folder)
    img = cv2.imread(str(files[0]), cv2.IMREAD_COLOR)
    if img is None:
        raise InputError(f"{files[0]}: cannot decode the image (corrupt?); replace or remove it")
    return CameraSource(folder.name, folder, tuple(files), img.shape[1], img.shape[0], len(files), None)


def _probe_video(path: Path) -> CameraSource:
    info = probe_video(path)
    return CameraSource(path.stem, path, None, info.width, info.height, info.num_frames, info.fps)


def parse_offsets(items: list[str] | dict[str, int] | None) -> dict[str, int]:
    """``["cam02=3", ...]`` (or a dict) -> {"cam02": 3}; InputError for anything else."""
    if not items:
        return {}
    if isinstance(items, dict):
        pairs = list(items.items())
    else:
        pairs = []
        for text in items:
            name, sep, value = str(text).partition("=")
            if not sep or not name.strip():
                raise InputError(f"--offset {text!r}: expected CAM=N, e.g. --offset cam02=3 (cam02's frame 3 is the "
                                 f"capture's frame 0)")
            pairs.append((name.strip(), value.strip()))
    out = {}
    for name, value in pairs:
        try:
            n = int(value)
        except (TypeError, ValueError):
            raise InputError(f"--offset {name}={value}: N must be a whole number of frames >= 0") from None
        if n < 0:
            raise InputError(f"--offset {name}={n}: N must be >= 0 (delay the other cameras instead)")
        out[str(name)] = n
    return out


class CaptureFiles:
    """The cameras of a capture folder with their synchronization.

    offsets: camera name -> first frame of that camera used (default 0).
    frame_range: (a, b) half-open, in synchronized frames; None = all of them (then every
      camera must have the same number of frames after its offset).
    ``frame(f, cam)`` -> (H, W, 3) uint8 RGB, raw (not undistorted).
    """

    def __init__(self, root: str | Path, offsets: dict[str, int] | None = None,
                 frame_range: tuple[int, int] | None = None) -> None:
        self.root = Path(root)
        if not self.root.is_dir():
            raise InputError(f"{self.root}: capture folder not found")
        videos = _videos(self.root)
        _check_one_kind(self.root, videos, _image_folders(self.root))
        if videos:
            self.sources = [_probe_video(p) for p in videos]
        else:
            folders = _image_folders(self.root)
            if not folders:
                raise InputError(f"{self.root}: no camera videos ({', '.join(VIDEO_EXTS)}) and no image folders "
                                 f"({', '.join(IMAGE_EXTS)}); put one video or one image folder per camera here")
            self.sources = [_probe_images(p) for p in folders]
        names = [s.name for s in self.sources]
        twice = sorted({n for n in names if names.count(n) > 1})
        if twice:
            raise InputError(f"{self.root}: camera names {twice} appear twice (same stem, different extensions); "
                             f"rename or remove one of each")
        self.offsets = parse_offsets(offsets)
        unknown = sorted(set(self.offsets) - set(names))
        if unknown:
            raise InputError(f"--offset names cameras {unknown} that this capture lacks; its cameras: {names}")
        self._check_rates()
        lengths = {s.name: s.num_frames - self.offsets.get(s.name, 0) for s in self.sources}
        short = [n for n, L in lengths.items() if L <= 0]
        if short:
            raise InputError(f"--offset: cameras {short} have no frame left after their offset "
                             f"({', '.join(f'{s.name}: {s.num_frames} frames' for s in self.sources if s.name in short)})")
        self.available = min(lengths.values())
        if frame_range is None:
            if len(set(lengths.values())) > 1:
                detail = ", ".join(f"{s.name} {s.num_frames}" + (f"-{self.offsets[s.name]}" if s.name in self.offsets else "")
                                   for s in self.sources)
                raise InputError(f"{self.root}: the cameras are not synchronized: frames per camera after the offsets: "
                                 f"{detail}; if a camera started late pass --offset CAM=N (its frame N is the others' "
                                 f"frame 0), else use the common part with --frames 0:{self.available}")
            frame_range = (0, self.available)
        a, b = int(frame_range[0]), int(frame_range[1])
        if not 0 <= a < b <= self.available:
            raise InputError(f"{self.root}: frame range {a}:{b} must satisfy 0 <= a < b <= {self.available} "
                             f"(the frames every camera has after its offset)")
        self.start, self.num_frames = a, b - a
        rates = [s.fps for s in self.sources if s.fps is not None]
        self.fps = float(rates[0]) if rates else IMAGE_FOLDER_FPS
        self._readers: dict[int, VideoReader] = {}
        self._lock = threading.Lock()

    def _check_rates(self) -> None:
        rates = {s.name: s.fps for s in self.sources if s.fps is not None}
        if rates and (max(rates.values()) - min(rates.values())) > FPS_RTOL * max(rates.values()):
            detail = ", ".join(f"{n} {r:.3f} fps" for n, r in rates.items())
            raise InputError(f"{self.root}: the cameras record at different frame rates ({detail}); a frame offset "
                             f"cannot synchronize them: re-encode the videos at one rate (e.g. ffmpeg -i in.mp4 "
                             f"-r 30 out.mp4)")

    @property
    def names(self) -> list[str]:
        return [s.name for s in self.sources]

    def source_frame(self, frame: int, cam: int) -> int:
        """The camera's own frame number of the capture's synchronized frame ``frame``."""
        return self.start + int(frame) + self.offsets.get(self.sources[cam].name, 0)

    def frame(self, frame: int, cam: int) -> np.ndarray:
        import cv2

        if not 0 <= frame < self.num_frames:
            raise InputError(f"{self.root}: frame {frame} out of range [0, {self.num_frames})")
        src = self.sources[cam]
        index = self.source_frame(frame, cam)
        if src.images is not None:
            img = cv2.imread(str(src.images[index]), cv2.IMREAD_COLOR)
            if img is None:
                raise InputError(f"{src.images[index]}: cannot decode the image (corrupt?); replace it")
            if img.shape[:2] != (src.height, src.width):
                raise InputError(f"{src.images[index]}: {img.shape[1]}x{img.shape[0]}, but the first image of "
                                 f"{src.name} is {src.width}x{src.height}; one camera's images must share one size")
            return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)
        with self._lock:
            if cam not in self._readers:
                self._readers[cam] = VideoReader(src.path)
            reader = self._readers[cam]
        return reader.frame(index)


def match_rig(rig: Rig, files: CaptureFiles, label: str) -> list[RigCamera]:
    """The rig's cameras in the capture's camera order, resized to the frames' size; InputError
    naming the cameras the calibration lacks or the sizes that do not fit."""
    by_name = rig.by_name()
    missing = [n for n in files.names if n not in by_name]
    if missing:
        raise InputError(f"{label}: no calibration for cameras {missing} (it has {sorted(by_name)}); name the "
                         f"calibration's cameras after the videos/folders, or recalibrate with `fixer4d calibrate`")
    out = []
    for s in files.sources:
        rc = by_name[s.name]
        if (rc.width, rc.height) != (s.width, s.height):
            if abs(rc.width / rc.height - s.width / s.height) > 0.01 * s.width / s.height:
                raise InputError(f"{label}: camera {s.name} is calibrated at {rc.width}x{rc.height} but its frames are "
                                 f"{s.width}x{s.height} (another aspect ratio); recalibrate with `fixer4d calibrate`")
            rc = rc.resized(s.width, s.height)
        out.append(rc)
    return out


class CaptureScene(MultiViewVideo):
    """A capture folder with its calibrated rig; frames undistorted onto pinhole cameras.

    Args:
      files: the capture's ``CaptureFiles`` (offsets and frame range applied).
      rig: the calibration (cameras matched by name); label: where it came from (for messages).
      scale: image scale. holdout: camera names evaluated held out (default none: all train).
      train_ids / test_ids: camera indices (sorted-name order) overriding the split.
    """

    def __init__(self, files: CaptureFiles, rig: Rig, label: str, scale: float = 1.0,
                 holdout: list[str] | None = None, train_ids: list[int] | None = None,
                 test_ids: list[int] | None = None, cache_mb: float = FRAME_CACHE_MB) -> None:
        super().__init__(cache_mb)
        if scale <= 0 or not np.isfinite(scale):
            raise InputError(f"{files.root}: scale must be > 0, got {scale}")
        self.files = files
        self.root = files.root
        self.name = files.root.name
        self.rig_label = label
        self.rig = rig
        self.num_frames = files.num_frames
        self.fps = files.fps
        self.scale = float(scale)
        self._rig_cameras = match_rig(rig, files, label)
        self.cameras = [rc.camera().scaled(scale) if scale != 1.0 else rc.camera() for rc in self._rig_cameras]
        self._maps: dict[int, tuple[np.ndarray, np.ndarray] | None] = {}
        self._maps_lock = threading.Lock()
        names = files.names
        holdout = list(holdout or [])
        unknown = [h for h in holdout if h not in names]
        if unknown:
            raise InputError(f"--holdout {', '.join(unknown)}: no such camera; this capture's cameras: {names}")
        if train_ids is not None or test_ids is not None:
            ids = range(len(names))
            te = [int(i) for i in (test_ids if test_ids is not None else [])]
            tr = [int(i) for i in (train_ids if train_ids is not None else [i for i in ids if i not in te])]
            bad = [i for i in tr + te if not 0 <= i < len(names)]
            if bad:
                raise InputError(f"{self.root}: camera ids {bad} out of range: a capture's ids are 0..{len(names) - 1} "
                                 f"in name order {names}")
        else:
            te = [names.index(h) for h in holdout]
            tr = [i for i in range(len(names)) if i not in te]
        if not tr:
            raise InputError(f"{self.root}: every camera is held out; leave at least two cameras to train on")
        self.train_ids, self.test_ids = tr, te

    def _undistort_maps(self, cam: int):
        with self._maps_lock:
            if cam not in self._maps:
                self._maps[cam] = undistort_maps(self._rig_cameras[cam])
            return self._maps[cam]

    def _load_frame(self, frame: int, cam: int) -> np.ndarray:
        import cv2

        img = undistort(self.files.frame(frame, cam), self._undistort_maps(cam)).astype(np.float32) / 255.0
        c = self.cameras[cam]
        if img.shape[:2] != (c.height, c.width):
            img = cv2.resize(img, (c.width, c.height), interpolation=cv2.INTER_AREA)
        return img

    def describe(self) -> str:
        held = "no held-out camera" if not self.test_ids else f"{len(self.test_ids)} held out"
        c = self.cameras[0]
        return (f"{self.name}: {len(self.cameras)} cameras ({len(self.train_ids)} train, {held}), {self.num_frames} "
                f"frames at {c.width}x{c.height}; calibration {self.rig_label}")
