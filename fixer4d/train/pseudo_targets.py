"""Stage 2's pseudo-targets: the restored frames of the cache, drawn as extra supervised views.

    targets = PseudoTargets(stage2, cache, refresh_cache, scene.train_cameras)
    targets.update(model, schedule.refresh_round(step))    # refresh / load the round in use
    loss = targets.loss(model, rng, render_view, timing)   # mean masked L1 over batch_pseudo frames

Each pseudo-view is rendered at its clip's time; a clip's frames at the train cameras themselves
(trajectory endpoints, alpha = 0 and 1) are skipped: real frames supervise those.
"""
from __future__ import annotations

import time
from collections import OrderedDict
from typing import Callable, Protocol, Sequence

import numpy as np
import torch

from fixer4d.errors import InputError
from fixer4d.geometry.camera import Camera
from fixer4d.model.snapshot import Snapshot
from fixer4d.model.spacetime import SpacetimeGaussians
from fixer4d.render.api import RenderOutput
from fixer4d.train.config import Stage2Config
from fixer4d.train.losses import masked_l1


class PseudoEntry(Protocol):
    """What stage 2 reads from a restoration cache entry (fixer4d.restore.cache.CacheEntry)."""

    key: str
    cameras: list[Camera]
    time: float

    def rgb(self) -> np.ndarray: ...

    def confidence(self) -> np.ndarray: ...

    def unobserved(self) -> np.ndarray | None: ...


class PseudoCache(Protocol):
    def entries(self, round: int | None = None) -> list[PseudoEntry]: ...

    def latest_round(self) -> int | None: ...


RefreshFn = Callable[[SpacetimeGaussians, int], None]
# ``render_view(snapshot, camera)``: the trainer's render of one view, which also records it for
# the densification statistics.
RenderView = Callable[[Snapshot, Camera], RenderOutput]


class PseudoTargets:
    """The cache round in use and its decoded clips.

    config: the Stage2Config (batch size, weighting, clip LRU size). cache: the restoration cache
    (``entries(round)``, ``latest_round()``). refresh_cache: ``refresh_cache(model, round)``
    re-renders and restores the trajectories into cache round ``round``; None = use the cache as
    it is. train_cameras: the observed cameras (their frames in a clip are not pseudo-views).
    """

    def __init__(self, config: Stage2Config, cache: PseudoCache, refresh_cache: RefreshFn | None,
                 train_cameras: Sequence[Camera], device: torch.device | str = "cpu") -> None:
        self.config = config
        self.device = torch.device(device)  # where decoded clips are kept (the training device)
        self.cache = cache
        self.refresh_cache = refresh_cache
        self.train_cameras = list(train_cameras)
        self.round = -1  # index of the cache round in use (-1 = none loaded yet)
        self.entries: list[PseudoEntry] = []
        self.entry_frames: list[np.ndarray] = []  # per entry: the clip frames used as pseudo-views
        self.entry_offsets = np.zeros(1, np.int64)  # (E+1,) start of each entry's frames in the flat pool
        self._clips: OrderedDict[str, tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]] = OrderedDict()

    def update(self, model: SpacetimeGaussians, due: int | None) -> None:
        """Before a step: refresh round ``due`` with the current model and load it (``due`` None:
        no refresh due); without a refresh callback, load the newest round once; after a resume,
        reload the round in use."""
        if due is not None:
            if self.refresh_cache is not None:
                with torch.no_grad():
                    self.refresh_cache(model, due)
                self.load_round(due)
            elif self.round < 0:
                self.load_round(self.cache.latest_round())
        elif not self.entries:
            self.load_round(self.round if self.round >= 0 else self.cache.latest_round())

    def forget(self, round: int) -> None:
        """Drop the loaded entries and clips and mark ``round`` as the one in use (a checkpoint
        was loaded: the next ``update`` reloads it)."""
        self.round = int(round)
        self.entries = []
        self._clips.clear()

    def load_round(self, r: int | None) -> None:
        """Load round ``r``'s entries; only their novel frames are pseudo-views (a trajectory's
        endpoints at alpha = 0 and 1 are the train cameras themselves, supervised by real frames)."""
        from fixer4d.geometry.trajectory import novel_frame_mask

        entries, frames = [], []
        for e in ([] if r is None else self.cache.entries(r)):
            novel = np.flatnonzero(novel_frame_mask(e.cameras, self.train_cameras)) if len(e.cameras) else []
            if len(novel):
                entries.append(e)
                frames.append(novel.astype(np.int64))
        if not entries:
            raise InputError(f"stage 2: the restoration cache has no entries with novel views for round {r}; run "
                             "the restore step (`fixer4d run`, or a refresh callback) before refining")
        self.round = int(r)
        self.entries = entries
        self.entry_frames = frames
        self.entry_offsets = np.concatenate([[0], np.cumsum([len(f) for f in frames])]).astype(np.int64)
        self._clips.clear()

    def clip(self, entry: PseudoEntry) -> tuple[torch.Tensor, torch.Tensor]:
        """(F,H,W,3) restored frames and (F,H,W) per-pixel weight of an entry's pseudo-loss,
        decoded on first use and kept in a small LRU (``max_cached_clips``)."""
        rgb, conf, _ = self._decoded(entry)
        return rgb, conf

    def evidence_weight(self, entry: PseudoEntry, frame: int) -> torch.Tensor:
        """(H,W) of clip frame ``frame``: the pseudo-loss weight times how unobserved each pixel is
        by the train cameras (the part of the loss that ``densify_stats = "evidence"`` lets densify)."""
        _, conf, hidden = self._decoded(entry)
        if hidden is None:
            raise InputError(f"cache entry {entry.key} has no unobserved-pixel map; refresh the cache or set "
                             "stage2.densify_stats to all or observed")
        return conf[frame] * hidden[frame]

    def _decoded(self, entry: PseudoEntry) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
        """(rgb, weight, unobserved or None) of an entry, decoded once into the LRU."""
        key = entry.key
        if key in self._clips:
            self._clips.move_to_end(key)
            return self._clips[key]
        rgb = torch.from_numpy(np.ascontiguousarray(entry.rgb(), dtype=np.float32)).to(self.device)
        conf = torch.from_numpy(np.ascontiguousarray(self.weight(entry), dtype=np.float32)).to(self.device)
        hidden = None
        if self.config.densify_stats == "evidence":
            unobserved = entry.unobserved()
            hidden = (None if unobserved is None else
                      torch.from_numpy(np.ascontiguousarray(unobserved, dtype=np.float32)).to(self.device))
        self._clips[key] = (rgb, conf, hidden)
        while len(self._clips) > max(self.config.max_cached_clips, 1):
            self._clips.popitem(last=False)
        return rgb, conf, hidden

    def weight(self, entry: PseudoEntry) -> np.ndarray:
        """(F, H, W) weight of the pseudo L1 (``Stage2Config``): the restorer's confidence (when
        ``confidence_weighting`` with ``pseudo_target = "restored"``; 1 for a gated target) times,
        with ``pseudo_mask = "unobserved"``, observed_weight + (1 - observed_weight) x how
        unobserved the pixel is by the train cameras."""
        s2 = self.config
        # a gated target already carries the confidence: the render stands wherever it is low
        weight = entry.confidence() if s2.confidence_weighting and s2.pseudo_target == "restored" else None
        if s2.pseudo_mask == "unobserved":
            hidden = entry.unobserved()
            if hidden is None:
                raise InputError(f"cache entry {entry.key} has no unobserved-pixel map (written with "
                                 "stage2.pseudo_mask=all); refresh the cache or set stage2.pseudo_mask=all")
            mask = s2.observed_weight + (1.0 - s2.observed_weight) * hidden
            weight = mask if weight is None else weight * mask
        if weight is None:
            weight = np.ones_like(entry.confidence())
        return weight

    def loss(self, model: SpacetimeGaussians, rng: np.random.Generator, render_view: RenderView,
             timing: dict[str, float], evidence: list[torch.Tensor] | None = None,
             l1: Callable[..., torch.Tensor] = masked_l1) -> torch.Tensor:
        """Mean over ``batch_pseudo`` cached novel frames, drawn uniformly from the loaded round
        with ``rng``, of the (confidence-weighted) L1 between the model rendered at the frame's
        camera *and its clip's time* and the restored frame. Adds seconds to ``timing``'s t_at
        and t_loss. ``evidence``, when given, receives per frame (in render order) its term of
        the same mean restricted to the pixels no train camera explains (``evidence_weight``).
        ``l1``: the weighted L1 (``masked_l1_device`` on a GPU trainer's hot path)."""
        s2 = self.config
        total = int(self.entry_offsets[-1])
        picks = rng.integers(0, total, size=s2.batch_pseudo)
        device = model.means.device  # the clips were decoded onto it (``_decoded``)
        loss = torch.zeros((), device=device)
        for flat in picks:
            e_idx = int(np.searchsorted(self.entry_offsets, flat, side="right") - 1)
            entry = self.entries[e_idx]
            f = int(self.entry_frames[e_idx][int(flat - self.entry_offsets[e_idx])])
            cam = entry.cameras[f]
            tic = time.perf_counter()
            snap = model.at(float(entry.time), camera_center=cam.center)
            timing["t_at"] += time.perf_counter() - tic
            out = render_view(snap, cam)
            tic = time.perf_counter()
            rgb, conf = self.clip(entry)
            target = rgb[f].to(device)
            if tuple(target.shape[:2]) != (cam.height, cam.width):
                raise InputError(f"cache entry {entry.key}: frame {f} is {tuple(target.shape[:2])} but its camera is "
                                 f"{cam.height}x{cam.width}; the cache is stale, refresh it")
            weighted = (s2.confidence_weighting and s2.pseudo_target == "restored") or s2.pseudo_mask != "all"
            weight = conf[f].to(device) if weighted else None
            loss = loss + l1(out.rgb, target, weight)
            if evidence is not None:
                evidence.append(l1(out.rgb, target, self.evidence_weight(entry, f).to(device)) / max(len(picks), 1))
            timing["t_loss"] += time.perf_counter() - tic
        return loss / max(len(picks), 1)
