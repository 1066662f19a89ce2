"""The on-disk restoration cache: restored clips that stage 2 uses as pseudo-targets.

Layout under the run folder (docs/design.md §11)::

    cache/round_<r>/t<frame:04d>_<i>-<j>[_arc<k> | _view<k>]/
        frame_0000.png ...   restored frames, 8-bit RGB
        confidence.npz       confidence (F, H, W) float16, frame_confidence (F,) float32
        meta.json            model step, restorer name + settings, trajectory (name, pair,
                             amplitude, cameras as Camera.to_dict()), time, frame, scores

Every entry is written with ``fixer4d.atomic.atomic_dir``: the files go to a hidden temporary
sibling which replaces the entry whole once complete, so a killed write leaves the previous
entry (or none), never half of one, and a refreshed entry never mixes old and new frames.
Readers skip hidden temporary directories (``clean_temporary`` deletes them).

Every visible entry directory is checked when it is read (meta.json parses and has this
layout's ``format``, every frame is a complete PNG, confidence.npz holds its two arrays). One
that fails is never silently skipped: a warning names the entry and the reason, the directory
is moved aside whole to ``cache/corrupt/round_<r>/<key>-<n>`` and the entry counts as missing,
so the pipeline restores it again. An entry of an older cache format, or one whose settings
``fingerprint`` differs from the cache's (the pipeline's key of every setting that changes a
pseudo-target), is moved to ``cache/stale/round_<r>/<key>-<n>`` the same way (one sentence per
cache for an older format). An entry of a newer format is refused with an InputError: it
belongs to a newer fixer4d and is left untouched.
"""
from __future__ import annotations

import hashlib
import json
import logging
import os
import re
import shutil
import threading
import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from fixer4d.atomic import atomic_dir, write_json
from fixer4d.errors import InputError
from fixer4d.geometry.camera import Camera
from fixer4d.psnr import psnr_from_mse
from fixer4d.restore.base import RestoreRequest, RestoreResult

META_FILE = "meta.json"
# meta.json cannot hold inf: a restored clip identical to its render reports this (the 1e-12 MSE floor)
CACHE_PSNR_MAX_DB = 120.0
CONFIDENCE_FILE = "confidence.npz"
FRAME_FILE = "frame_{:04d}.png"
ROUND_DIR = "round_{}"
_ROUND_RE = re.compile(r"^round_(\d+)$")
CORRUPT_DIR = "corrupt"  # cache/corrupt/round_<r>/<key>-<n>: unreadable or foreign entries, set aside
STALE_DIR = "stale"  # cache/stale/round_<r>/<key>-<n>: older-format or other-settings entries, set aside
# Version of the entry layout written into meta.json, bumped when the files change meaning.
# 1: frames + confidence.npz + meta.json; 2: meta.json also carries the settings "fingerprint".
CACHE_FORMAT = 2
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_PNG_END = b"IEND\xaeB`\x82"  # the IEND chunk type + CRC: the last 8 bytes of every complete PNG
_CONFIDENCE_ARRAYS = ("confidence.npy", "frame_confidence.npy")

log = logging.getLogger("fixer4d.restore")
# Render alpha below this counts as a hole when scoring how much an entry repaired
# (the same threshold as the restorer's trusted-depth alpha).
SCORE_HOLE_ALPHA = 0.5


@dataclass
class CacheEntry:
    """A complete cache entry on disk. ``rgb()`` and ``confidence()`` read the files on demand."""

    path: Path
    key: str
    round: int
    meta: dict[str, Any]
    cameras: list[Camera] = field(repr=False)
    time: float
    frame: int

    @property
    def num_frames(self) -> int:
        return len(self.cameras)

    def rgb(self) -> np.ndarray:
        """(F, H, W, 3) float32 in [0, 1]: the restored clip."""
        frames = []
        for k in range(self.num_frames):
            img = cv2.imread(str(self.path / FRAME_FILE.format(k)), cv2.IMREAD_COLOR)
            if img is None:
                raise InputError(f"cache entry {self.path}: {FRAME_FILE.format(k)} is missing or unreadable; "
                                 "delete the entry so that it is restored again")
            frames.append(img[..., ::-1].astype(np.float32) / 255.0)
        return np.stack(frames)

    def confidence(self) -> np.ndarray:
        """(F, H, W) float32 in [0, 1]: per-pixel confidence of the restored clip."""
        with np.load(self.path / CONFIDENCE_FILE, allow_pickle=False) as data:
            return data["confidence"].astype(np.float32)

    def unobserved(self) -> np.ndarray | None:
        """(F, H, W) float32 in [0, 1]: how unobserved each pixel is by the train cameras
        (``restore.visibility``), or None for an entry written without it."""
        with np.load(self.path / CONFIDENCE_FILE, allow_pickle=False) as data:
            return data["unobserved"].astype(np.float32) if "unobserved" in data.files else None

    def frame_confidence(self) -> np.ndarray:
        """(F,) float32 per-frame confidence."""
        with np.load(self.path / CONFIDENCE_FILE, allow_pickle=False) as data:
            return data["frame_confidence"].astype(np.float32)


def settings_fingerprint(settings: Any) -> str:
    """A short stable key of JSON-able ``settings`` (every setting that changes a pseudo-target:
    restorer and its settings, trajectories, model state, ...): entries written under another
    fingerprint are stale for a cache opened with this one."""
    text = json.dumps(settings, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha1(text.encode("utf-8")).hexdigest()[:16]


class _Unusable(Exception):
    """An entry directory that cannot be used; ``kind`` is CORRUPT_DIR or STALE_DIR."""

    def __init__(self, kind: str, reason: str, reported: bool = False) -> None:
        super().__init__(reason)
        self.kind = kind
        self.reason = reason
        self.reported = reported  # already said once for the whole cache (an older format)


class RestoreCache:
    """Restored clips by round and key under ``root`` (``runs/<name>/cache``).

    fingerprint: the key of the settings this cache serves (``settings_fingerprint``); written
    into every entry, and entries carrying another one are set aside as stale. None accepts
    entries of any settings (a viewer inspecting a run folder).
    ``set_aside`` lists (entry path before the move, where it went, reason) of every entry this
    instance moved aside, for reports.
    """

    def __init__(self, root: str | Path, fingerprint: str | None = None) -> None:
        self.root = Path(root)
        self.fingerprint = fingerprint
        self.set_aside: list[tuple[Path, Path, str]] = []
        self._told_older = False
        self._lock = threading.Lock()  # moving aside from restore-job threads and the trainer at once

    # ---- naming ------------------------------------------------------------------------
    @staticmethod
    def key(frame: int, i: int, j: int, arc: int | None = None, view: int | None = None) -> str:
        """Entry name of the clip at frame ``frame`` on the trajectory of pair (i, j) [arc k], or
        on the path to undetermined view ``view`` whose references are (i, j)."""
        base = f"t{int(frame):04d}_{int(i)}-{int(j)}"
        if view is not None:
            return f"{base}_view{int(view)}"
        return base if arc is None else f"{base}_arc{int(arc)}"

    def round_dir(self, round: int) -> Path:
        return self.root / ROUND_DIR.format(int(round))

    def entry_dir(self, round: int, key: str) -> Path:
        if not key or "/" in key or "\\" in key or key.startswith(".") or key in ("..",):
            raise InputError(f"restore cache: {key!r} is not a valid entry key; use RestoreCache.key(frame, i, j, arc)")
        return self.round_dir(round) / key

    # ---- writing -----------------------------------------------------------------------
    def write(self, round: int, key: str, request: RestoreRequest, result: RestoreResult,
              meta: dict[str, Any]) -> CacheEntry:
        """Write (or replace) entry ``key`` of round ``round`` atomically; returns it.

        meta.json = ``meta`` (model step, restorer name and settings, ...) plus the layout's own
        fields: key, round, frame, time, trajectory (request.trajectory + cameras), size, scores.
        """
        if result.rgb.shape[:3] != request.rgb.shape[:3]:
            raise InputError(f"restore cache {key}: result shape {result.rgb.shape} does not match the request "
                             f"{request.rgb.shape}")
        path = self.entry_dir(round, key)
        F, H, W = result.rgb.shape[:3]
        rgb8 = np.round(np.clip(np.nan_to_num(result.rgb, nan=0.0), 0.0, 1.0) * 255.0).astype(np.uint8)
        scores = dict(meta.get("scores", {}))
        scores.update(self._scores(request, result))
        record = dict(meta)
        record.update({
            "format": CACHE_FORMAT, "fingerprint": self.fingerprint,
            "key": key, "round": int(round), "frame": request.frame, "time": request.time,
            "num_frames": F, "width": W, "height": H,
            "trajectory": {**request.trajectory, "cameras": [c.to_dict() for c in request.cameras]},
            "scores": scores,
        })
        with atomic_dir(path) as tmp:
            for k in range(F):
                _write_png(tmp / FRAME_FILE.format(k), rgb8[k])
            np.savez_compressed(tmp / CONFIDENCE_FILE,
                                confidence=np.clip(result.confidence, 0.0, 1.0).astype(np.float16),
                                frame_confidence=result.frame_confidence.astype(np.float32),
                                **({} if request.unobserved is None else
                                   {"unobserved": np.clip(request.unobserved, 0.0, 1.0).astype(np.float16)}))
            # meta.json last: an entry directory without it is never treated as complete
            write_json(tmp / META_FILE, record)
        return self._load(path, int(round))

    @staticmethod
    def _scores(request: RestoreRequest, result: RestoreResult) -> dict[str, Any]:
        hole = np.nan_to_num(request.alpha, nan=0.0) < SCORE_HOLE_ALPHA
        return {
            "mean_confidence": float(result.confidence.mean()),
            "frame_confidence": [float(c) for c in result.frame_confidence],
            "render_hole_fraction": float(hole.mean()),
            "psnr_restored_vs_render": _restored_vs_render_psnr(result.rgb, request.rgb),
            # the share of the clip's pixels left to pseudo-supervision (None: not computed)
            "unobserved_fraction": None if request.unobserved is None else float(np.mean(request.unobserved)),
        }

    # ---- reading -----------------------------------------------------------------------
    def has(self, round: int, key: str) -> bool:
        """Whether a complete entry ``key`` exists in round ``round`` (reuse it on resume)."""
        return self._load(self.entry_dir(round, key), int(round)) is not None

    def get(self, round: int, key: str) -> CacheEntry | None:
        """The complete entry ``key`` of round ``round``, or None."""
        return self._load(self.entry_dir(round, key), int(round))

    def rounds(self) -> list[int]:
        """Rounds holding at least one complete entry, ascending."""
        if not self.root.is_dir():
            return []
        found = []
        for d in self.root.iterdir():
            m = _ROUND_RE.match(d.name)
            if m and d.is_dir() and any(self._load(e, int(m.group(1))) is not None for e in self._entry_dirs(d)):
                found.append(int(m.group(1)))
        return sorted(found)

    def latest_round(self) -> int | None:
        """The highest round with a complete entry, or None when the cache is empty."""
        rounds = self.rounds()
        return rounds[-1] if rounds else None

    def entries(self, round: int | None = None) -> list[CacheEntry]:
        """Complete entries of ``round`` sorted by key (None = the latest round)."""
        if round is None:
            round = self.latest_round()
            if round is None:
                return []
        out = []
        for d in self._entry_dirs(self.round_dir(round)):
            entry = self._load(d, int(round))
            if entry is not None:
                out.append(entry)
        return out

    def clean_temporary(self) -> int:
        """Delete temporary directories left by killed writes; returns how many were removed."""
        removed = 0
        if not self.root.is_dir():
            return 0
        for rd in self.root.iterdir():
            if not (_ROUND_RE.match(rd.name) and rd.is_dir()):
                continue
            for d in rd.iterdir():
                if d.is_dir() and d.name.startswith(".") and (".tmp." in d.name or ".old." in d.name):
                    shutil.rmtree(d, ignore_errors=True)
                    removed += 1
        return removed

    @staticmethod
    def _entry_dirs(round_dir: Path) -> list[Path]:
        if not round_dir.is_dir():
            return []
        return sorted(d for d in round_dir.iterdir() if d.is_dir() and not d.name.startswith("."))

    def _load(self, path: Path, round: int) -> CacheEntry | None:
        """The complete, current entry at ``path``; None when there is none. An entry directory
        that cannot be used is reported and moved aside (see the module doc), then None."""
        if not path.is_dir():
            return None
        try:
            return self._check(path, round)
        except _Unusable as bad:
            self._move_aside(path, round, bad)
            return None

    def _check(self, path: Path, round: int) -> CacheEntry:
        """Validate the entry directory ``path``; raises _Unusable saying why it cannot be used."""
        try:
            meta = json.loads((path / META_FILE).read_text())
        except FileNotFoundError:
            raise _Unusable(CORRUPT_DIR, f"no {META_FILE} (an entry copied in half, or not a cache entry)") from None
        except (OSError, ValueError) as exc:
            raise _Unusable(CORRUPT_DIR, f"unreadable {META_FILE} ({type(exc).__name__}: {exc})") from None
        if not isinstance(meta, dict):
            raise _Unusable(CORRUPT_DIR, f"{META_FILE} holds a {type(meta).__name__}, not an object")
        fmt = meta.get("format")
        if not isinstance(fmt, int) or isinstance(fmt, bool):
            raise _Unusable(CORRUPT_DIR, f"{META_FILE} has no cache format version (a foreign folder)")
        if fmt > CACHE_FORMAT:
            raise InputError(f"restore cache entry {path}: cache format {fmt}, but this fixer4d reads format "
                             f"{CACHE_FORMAT}; open the run with the newer fixer4d that wrote it, or use a new --out")
        if fmt < CACHE_FORMAT:
            if not self._told_older:
                self._told_older = True
                log.warning("restore cache %s: written in cache format %d, this fixer4d writes format %d; its "
                            "entries are moved to %s/ and restored again", self.root, fmt, CACHE_FORMAT,
                            self.root / STALE_DIR)
            raise _Unusable(STALE_DIR, f"older cache format {fmt} (now {CACHE_FORMAT})", reported=True)
        if self.fingerprint is not None and meta.get("fingerprint") != self.fingerprint:
            raise _Unusable(STALE_DIR, f"written for other settings (fingerprint {meta.get('fingerprint')!r}, "
                                       f"now {self.fingerprint!r})")
        try:
            cameras = [Camera.from_dict(c) for c in meta["trajectory"]["cameras"]]
            num_frames, time, frame = int(meta["num_frames"]), float(meta["time"]), int(meta["frame"])
        except (KeyError, TypeError, ValueError, InputError) as exc:
            raise _Unusable(CORRUPT_DIR, f"malformed {META_FILE} ({type(exc).__name__}: {exc})") from None
        if len(cameras) != num_frames:
            raise _Unusable(CORRUPT_DIR, f"{META_FILE} lists {len(cameras)} cameras for {num_frames} frames")
        for k in range(num_frames):
            name = FRAME_FILE.format(k)
            if not _complete_png(path / name):
                raise _Unusable(CORRUPT_DIR, f"{name} is missing or not a complete PNG")
        try:
            with zipfile.ZipFile(path / CONFIDENCE_FILE) as z:
                names = set(z.namelist())
        except (OSError, zipfile.BadZipFile) as exc:
            raise _Unusable(CORRUPT_DIR, f"{CONFIDENCE_FILE} is missing or unreadable ({exc})") from None
        missing = [a for a in _CONFIDENCE_ARRAYS if a not in names]
        if missing:
            raise _Unusable(CORRUPT_DIR, f"{CONFIDENCE_FILE} lacks {missing}")
        return CacheEntry(path, path.name, round, meta, cameras, time, frame)

    def _move_aside(self, path: Path, round: int, bad: _Unusable) -> None:
        """Move the entry directory ``path`` to cache/<kind>/round_<r>/<key>-<n> and report it."""
        with self._lock:
            dest_dir = self.root / bad.kind / ROUND_DIR.format(int(round))
            dest_dir.mkdir(parents=True, exist_ok=True)
            n = 0
            while (dest_dir / f"{path.name}-{n}").exists():
                n += 1
            dest = dest_dir / f"{path.name}-{n}"
            try:
                os.replace(path, dest)
            except FileNotFoundError:  # another reader moved it first
                return
        self.set_aside.append((path, dest, bad.reason))
        if not bad.reported:
            log.warning("restore cache entry %s: %s; moved to %s, it will be restored again", path, bad.reason, dest)


def _complete_png(path: Path) -> bool:
    """Whether ``path`` starts with the PNG signature and ends with the IEND chunk (a write that
    stopped early, or a file cut short, does not)."""
    try:
        with open(path, "rb") as fh:
            if fh.read(len(_PNG_SIGNATURE)) != _PNG_SIGNATURE:
                return False
            fh.seek(0, os.SEEK_END)
            if fh.tell() < len(_PNG_SIGNATURE) + len(_PNG_END):
                return False
            fh.seek(-len(_PNG_END), os.SEEK_END)
            return fh.read(len(_PNG_END)) == _PNG_END
    except OSError:
        return False


def _write_png(path: Path, rgb8: np.ndarray) -> None:
    """Write one (H, W, 3) uint8 RGB frame as PNG."""
    if not cv2.imwrite(str(path), np.ascontiguousarray(rgb8[..., ::-1])):
        raise OSError(f"could not write {path}")


def _restored_vs_render_psnr(restored: np.ndarray, render: np.ndarray) -> float:
    """PSNR (dB, at most CACHE_PSNR_MAX_DB) of a restored clip against the render it started from."""
    target = np.clip(np.nan_to_num(render, nan=0.0), 0, 1).astype(np.float64)
    mse = float(np.mean((restored.astype(np.float64) - target) ** 2))
    return psnr_from_mse(mse, CACHE_PSNR_MAX_DB)
