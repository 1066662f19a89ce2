"""The Dynamic3DGaussians / CMU Panoptic layout.

train_meta.json and test_meta.json: {"w", "h", "k": [T][C] 3x3, "w2c": [T][C] 4x4 (OpenCV
axes), "fn": [T][C] "<cam>/<frame:06d>.jpg", "cam_id": [T][C]}; images under ims/, foreground
masks (optional) under seg/ with the same names as .png. The cameras are static, so frame 0's
k and w2c define the rig. Train = the train_meta cameras, test = the test_meta cameras.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from fixer4d.errors import InputError
from fixer4d.geometry.camera import Camera
from fixer4d.jsonfile import read_json_object
from fixer4d.scene.base import FRAME_CACHE_MB, MultiViewVideo

# Panoptic Studio HD cameras record at 30 fps (the metadata carries no rate).
PANOPTIC_FPS = 30.0
# Segmentation PNGs are 0/255 (sometimes antialiased): foreground where above half.
MASK_THRESHOLD = 0.5


def _read_meta(path: Path) -> dict:
    if not path.is_file():
        raise InputError(f"{path}: file not found; a Dynamic3DGaussians/Panoptic folder needs train_meta.json "
                         f"and test_meta.json next to ims/")
    meta = read_json_object(path, str(path), "re-download or regenerate it")
    missing = [k for k in ("w", "h", "k", "w2c", "fn", "cam_id") if k not in meta]
    if missing:
        raise InputError(f"{path}: missing keys {missing}; expected w, h, k, w2c, fn, cam_id")
    T = len(meta["fn"])
    for key in ("k", "w2c", "cam_id"):
        if len(meta[key]) != T:
            raise InputError(f"{path}: '{key}' has {len(meta[key])} frames but 'fn' has {T}; the metadata is inconsistent")
    return meta


class PanopticScene(MultiViewVideo):
    """A Dynamic3DGaussians-format capture (e.g. panoptic_basketball): JPEG frames, static rig.

    Args:
      root: folder with train_meta.json, test_meta.json, ims/ (and seg/).
      scale: image scale; frame_range: (a, b) half-open frame range.
      train_ids / test_ids: Panoptic camera ids overriding the metadata split (each must appear
        in one of the two metadata files).
    """

    def __init__(self, root: str | Path, scale: float = 1.0, frame_range: tuple[int, int] | None = None,
                 train_ids: list[int] | None = None, test_ids: list[int] | None = None,
                 cache_mb: float = FRAME_CACHE_MB) -> None:
        super().__init__(cache_mb)
        self.root = Path(root)
        self.name = self.root.name
        self.fps = PANOPTIC_FPS
        if scale <= 0 or not np.isfinite(scale):
            raise InputError(f"{self.root}: scale must be > 0, got {scale}")
        metas = {"train": _read_meta(self.root / "train_meta.json")}
        test_path = self.root / "test_meta.json"
        metas["test"] = _read_meta(test_path) if test_path.is_file() else None
        T = len(metas["train"]["fn"])
        if metas["test"] is not None and len(metas["test"]["fn"]) != T:
            raise InputError(f"{test_path}: {len(metas['test']['fn'])} frames but train_meta.json has {T}; "
                             f"both must describe the same clip")
        # cam_id -> (intrinsics, w2c, per-frame file names)
        found: dict[int, tuple[np.ndarray, np.ndarray, list[str], int, int]] = {}
        split: dict[str, list[int]] = {"train": [], "test": []}
        for which, meta in metas.items():
            if meta is None:
                continue
            w, h = int(meta["w"]), int(meta["h"])
            for c, cid in enumerate(meta["cam_id"][0]):
                cid = int(cid)
                k = np.asarray(meta["k"][0][c], np.float64)
                w2c = np.asarray(meta["w2c"][0][c], np.float64)
                if k.shape != (3, 3) or w2c.shape != (4, 4) or not (np.all(np.isfinite(k)) and np.all(np.isfinite(w2c))):
                    raise InputError(f"{self.root / f'{which}_meta.json'}: camera {cid} has a malformed or non-finite "
                                     f"k (3x3) / w2c (4x4); fix the metadata")
                files = []
                for f in range(T):
                    ids = [int(x) for x in meta["cam_id"][f]]
                    if cid not in ids:
                        raise InputError(f"{self.root / f'{which}_meta.json'}: camera {cid} is missing at frame {f}; "
                                         f"every frame must list the same cameras")
                    files.append(meta["fn"][f][ids.index(cid)])
                found[cid] = (k, w2c, files, w, h)
                split[which].append(cid)

        if train_ids is not None or test_ids is not None:
            tr = [int(i) for i in (train_ids if train_ids is not None else split["train"])]
            te = [int(i) for i in (test_ids if test_ids is not None else [i for i in found if i not in tr])]
        else:
            tr, te = split["train"], split["test"]
        unknown = [i for i in tr + te if i not in found]
        if unknown:
            raise InputError(f"{self.root}: camera ids {unknown} are in neither train_meta.json nor test_meta.json; "
                             f"available: {sorted(found)}")
        te = [i for i in te if i not in tr]
        self.camera_ids = tr + te
        if frame_range is None:
            frame_range = (0, T)
        a, b = int(frame_range[0]), int(frame_range[1])
        if not 0 <= a < b <= T:
            raise InputError(f"{self.root}: frame_range {frame_range} must satisfy 0 <= a < b <= {T}")
        self.frame_offset = a
        self.num_frames = b - a
        self.cameras = []
        self._files = []
        for cid in self.camera_ids:
            k, w2c, files, w, h = found[cid]
            cam = Camera(k, np.linalg.inv(w2c), w, h, str(cid))
            self.cameras.append(cam.scaled(scale) if scale != 1.0 else cam)
            self._files.append(files)
        self.scale = float(scale)
        self.train_ids = list(range(len(tr)))
        self.test_ids = list(range(len(tr), len(tr) + len(te)))
        # Fail now, not mid-training, when an image the rig needs is absent.
        for cam, files in enumerate(self._files):
            for f in (a, b - 1):
                p = self.root / "ims" / files[f]
                if not p.is_file():
                    raise InputError(f"{p}: image missing (camera {self.camera_ids[cam]}, frame {f}); "
                                     f"restore the ims/ folder or pass a frame_range that avoids it")

    def _read(self, path: Path, flags: int) -> np.ndarray:
        import cv2

        if not path.is_file():
            raise InputError(f"{path}: image missing; restore the ims/ (or seg/) folder of the scene")
        img = cv2.imread(str(path), flags)
        if img is None:
            raise InputError(f"{path}: cannot decode the image (corrupt?); re-download the scene")
        return img

    def _resize(self, img: np.ndarray, cam: int, interp: int) -> np.ndarray:
        import cv2

        c = self.cameras[cam]
        if img.shape[:2] != (c.height, c.width):
            img = cv2.resize(img, (c.width, c.height), interpolation=interp)
        return img

    def _load_frame(self, frame: int, cam: int) -> np.ndarray:
        import cv2

        path = self.root / "ims" / self._files[cam][self.frame_offset + frame]
        img = self._read(path, cv2.IMREAD_COLOR)
        rgb = cv2.cvtColor(img, cv2.COLOR_BGR2RGB).astype(np.float32) / 255.0
        return self._resize(rgb, cam, cv2.INTER_AREA)

    def _load_mask(self, frame: int, cam: int) -> np.ndarray | None:
        import cv2

        name = Path(self._files[cam][self.frame_offset + frame]).with_suffix(".png")
        path = self.root / "seg" / name
        if not path.is_file():
            return None
        m = self._read(path, cv2.IMREAD_GRAYSCALE).astype(np.float32) / 255.0
        return self._resize(m, cam, cv2.INTER_AREA) > MASK_THRESHOLD
