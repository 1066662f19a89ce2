"""Per-frame coloured point clouds, the output of initialization, and their PLY files.

One file per frame, ``frame_XXXX.ply``: vertex properties x, y, z (float32), red, green, blue
(uint8, what every point-cloud viewer reads) and time (float32, the frame's t = f / T, the same
for every point). The frame index is stored in a header comment. Colours come back quantized to
1/255.
"""
from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fixer4d.atomic import atomic_path
from fixer4d.errors import InputError

_NAME = re.compile(r"^frame_(\d{4,})\.ply$")


@dataclass
class FrameCloud:
    """Points of one timestamp.

    frame: frame index f. time: t = f / T. points: (N, 3) float32 world positions.
    colors: (N, 3) float32 RGB in [0, 1].
    """

    frame: int
    time: float
    points: np.ndarray
    colors: np.ndarray

    def __post_init__(self) -> None:
        self.points = np.ascontiguousarray(np.asarray(self.points, dtype=np.float32).reshape(-1, 3))
        self.colors = np.ascontiguousarray(np.asarray(self.colors, dtype=np.float32).reshape(-1, 3))
        if self.points.shape[0] != self.colors.shape[0]:
            raise InputError(f"frame {self.frame}: {self.points.shape[0]} points but {self.colors.shape[0]} colours")
        if not np.all(np.isfinite(self.points)):
            raise InputError(f"frame {self.frame}: non-finite point positions; filter them before building the cloud")
        self.colors = np.clip(np.nan_to_num(self.colors, nan=0.0), 0.0, 1.0)

    def __len__(self) -> int:
        return int(self.points.shape[0])

    @property
    def times(self) -> np.ndarray:
        """(N,) float32: every point carries its frame time."""
        return np.full(len(self), self.time, dtype=np.float32)


def frame_filename(frame: int) -> str:
    return f"frame_{frame:04d}.ply"


def save_frame_cloud(path: str | Path, cloud: FrameCloud) -> Path:
    """Write one cloud as a binary PLY, atomically."""
    from plyfile import PlyData, PlyElement

    dtype = [("x", "f4"), ("y", "f4"), ("z", "f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1"), ("time", "f4")]
    vert = np.empty(len(cloud), dtype=dtype)
    for i, axis in enumerate("xyz"):
        vert[axis] = cloud.points[:, i]
    rgb = np.round(cloud.colors * 255.0).astype(np.uint8)
    for i, ch in enumerate(("red", "green", "blue")):
        vert[ch] = rgb[:, i]
    vert["time"] = cloud.time
    ply = PlyData([PlyElement.describe(vert, "vertex")], text=False,
                  comments=[f"fixer4d frame {cloud.frame}", f"fixer4d time {cloud.time!r}"])
    with atomic_path(path) as tmp:
        ply.write(str(tmp))
    return Path(path)


def load_frame_cloud(path: str | Path) -> FrameCloud:
    """Read a file written by ``save_frame_cloud``."""
    from plyfile import PlyData

    path = Path(path)
    try:
        ply = PlyData.read(str(path))
        v = ply["vertex"].data
        points = np.stack([v["x"], v["y"], v["z"]], 1)
        colors = np.stack([v["red"], v["green"], v["blue"]], 1).astype(np.float32) / 255.0
    except (OSError, KeyError, ValueError) as exc:
        raise InputError(f"{path}: not a fixer4d frame cloud PLY ({exc}); rerun `fixer4d init`") from exc
    frame, time = None, None
    for c in ply.comments:
        if c.startswith("fixer4d frame "):
            frame = int(c.split()[-1])
        elif c.startswith("fixer4d time "):
            time = float(c.split()[-1])
    m = _NAME.match(path.name)
    if frame is None and m:
        frame = int(m.group(1))
    if time is None and len(v):
        time = float(v["time"][0])
    if frame is None or time is None:
        raise InputError(f"{path}: frame index or time missing from the PLY; rerun `fixer4d init`")
    return FrameCloud(frame, time, points, colors)


def save_frame_clouds(out_dir: str | Path, clouds: list[FrameCloud]) -> list[Path]:
    """One PLY per frame, ``out_dir/frame_XXXX.ply``, each written atomically."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    return [save_frame_cloud(out_dir / frame_filename(c.frame), c) for c in clouds]


def load_frame_clouds(out_dir: str | Path) -> list[FrameCloud]:
    """Every ``frame_XXXX.ply`` in ``out_dir``, sorted by frame."""
    out_dir = Path(out_dir)
    if not out_dir.is_dir():
        raise InputError(f"{out_dir}: no such init folder; run `fixer4d init SCENE --out {out_dir}` first")
    files = sorted(p for p in out_dir.iterdir() if _NAME.match(p.name))
    if not files:
        raise InputError(f"{out_dir}: no frame_XXXX.ply files; run `fixer4d init SCENE --out {out_dir}` first")
    return sorted((load_frame_cloud(p) for p in files), key=lambda c: c.frame)


def merge_clouds(clouds: list[FrameCloud]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """All frames' points together: (points (N,3), colors (N,3), times (N,)), the input of
    ``SpacetimeGaussians.from_points``."""
    if not clouds:
        return np.zeros((0, 3), np.float32), np.zeros((0, 3), np.float32), np.zeros(0, np.float32)
    return (np.concatenate([c.points for c in clouds]), np.concatenate([c.colors for c in clouds]),
            np.concatenate([c.times for c in clouds]))
