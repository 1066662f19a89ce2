"""Two stage-1 fields trained side by side that prune each other (CoR-GS, ECCV 2024).

    a, _ = stage1_trainer(ctx, init, run_dir)           # field A: the stage-1 model
    co = CoFields(a, twin_trainer(a, terms, run_dir), config.co_fields)
    co.resume(); co.train()                              # co.b.model: field B, the twin

Field B starts from a copy of field A's initial model and trains with another seed
(``TWIN_SEED_OFFSET``): its densification splits, frame order and view draws differ. Where the
train cameras pin the scene down both fields converge to the same surfaces; where they do not,
each grows Gaussians the other has no counterpart for. Every ``prune_every`` densification rounds,
right after the round, each field loses its non-frozen Gaussians whose nearest Gaussian of the
other field (by ``means``, the position at a Gaussian's own time centre) is farther than
``prune_distance`` x the scene extent. The optimizer's moments and the densification statistics
are pruned with the rows.

Both trainers step in one process, in chunks that end at the co-pruning steps: A trains to the
next one, then B, then they prune each other. Checkpoints: A's under RUN/checkpoints, B's under
RUN/twin/checkpoints, written by each trainer at its usual steps and at the end of every chunk,
i.e. before that step's co-pruning (the pruning is a function of the two models alone, so
``resume`` repeats it). ``resume`` loads the newest step that both fields hold a checkpoint of;
where there is none (a kill before B's first save) it deletes both fields' checkpoints and the
stage restarts from the initial model.
"""
from __future__ import annotations

import copy
import dataclasses
import logging
import time
from pathlib import Path

import numpy as np
import torch
from scipy.spatial import cKDTree

from fixer4d.model.densify import DensifyStats, prune_gaussians
from fixer4d.model.term_revisions import TemporalStats
from fixer4d.model.terms import ModelTermsConfig
from fixer4d.train.checkpoints import list_checkpoints, read_checkpoint, remove_partial_checkpoints
from fixer4d.train.co_fields_config import CoFieldsConfig
from fixer4d.train.fields import FIELD_SEED_OFFSET
from fixer4d.train.trainer import Trainer

log = logging.getLogger("fixer4d.train")

# Field B's seed is field A's plus this: the offset of a second stage-1 field (train.fields).
TWIN_SEED_OFFSET = FIELD_SEED_OFFSET
# Field B's folder inside the run folder (its checkpoints), and field B itself beside field A's
# model_stage1.ply.
TWIN_DIR = "twin"
TWIN_NAME = "model_stage1_twin.ply"


def unsupported(means: np.ndarray, other: np.ndarray, distance: float) -> np.ndarray:
    """(N,) bool: the points of ``means`` (N, 3) whose nearest point of ``other`` (M, 3) is farther
    than ``distance`` (world units); all True when ``other`` is empty."""
    if len(other) == 0:
        return np.ones(len(means), bool)
    nearest, _ = cKDTree(other).query(means, k=1)
    return nearest > distance


def prune_trainer(trainer: Trainer, keep: torch.Tensor) -> None:
    """Keep ``keep`` (N,) bool of ``trainer``'s Gaussians: the model, Adam's moments, and the
    densification (and term-revision) statistics, row for row."""
    keep = keep.to(device=trainer.model.means.device, dtype=torch.bool)
    prune_gaussians(trainer.model, trainer.optimizer, keep)
    s = trainer.stats
    trainer.stats = DensifyStats(s.grad_accum[keep], s.denom[keep], s.max_radii[keep])
    ts = trainer.temporal_stats
    if len(ts) == len(keep):  # empty unless the trainer revises model terms
        trainer.temporal_stats = TemporalStats(ts.grad[keep], ts.count[keep])


def co_prune(a: Trainer, b: Trainer, distance_fraction: float) -> dict[str, int]:
    """Prune each field's non-frozen Gaussians that the other does not support (``unsupported`` at
    ``distance_fraction`` x A's scene extent). A field is never pruned to nothing. Returns
    {"pruned_a", "pruned_b"}."""
    with a._lock, b._lock, torch.no_grad():
        ma = a.model.means.detach().cpu().double().numpy()
        mb = b.model.means.detach().cpu().double().numpy()
        distance = distance_fraction * a.extent
        drops = [unsupported(ma, mb, distance) & ~a.model.frozen.cpu().numpy(),
                 unsupported(mb, ma, distance) & ~b.model.frozen.cpu().numpy()]
        counts = {}
        for name, trainer, drop in (("a", a, drops[0]), ("b", b, drops[1])):
            pruned = int(drop.sum()) if not drop.all() else 0
            if pruned:
                prune_trainer(trainer, torch.from_numpy(~drop))
            counts[f"pruned_{name}"] = pruned
    return counts


def twin_trainer(a: Trainer, terms: ModelTermsConfig | None, run_dir: str | Path | None) -> Trainer:
    """Field B of ``a`` (an untrained stage-1 trainer): a copy of its model and camera response,
    its config with the seed moved by ``TWIN_SEED_OFFSET``, checkpoints under RUN/twin.
    terms: what ``a`` was built with (None: no term revisions)."""
    cfg = dataclasses.replace(a.config, seed=a.config.seed + TWIN_SEED_OFFSET)
    return Trainer(copy.deepcopy(a.model), a.scene, cfg, run_dir=None if run_dir is None else Path(run_dir) / TWIN_DIR,
                   terms=terms, camera_response=copy.deepcopy(a.response))


class CoFields:
    """Trains field A (``a``) and field B (``b``) side by side with co-pruning (module docstring).

    ``prune_steps`` are the (1-based) steps after which they prune each other; ``history`` holds
    one record per co-pruning ({"step", "pruned_a", "pruned_b", "seconds"}); ``seconds`` is the
    time spent co-pruning.
    """

    def __init__(self, a: Trainer, b: Trainer, config: CoFieldsConfig) -> None:
        self.a, self.b, self.config = a, b, config
        every = a.config.densify_every
        rounds = [s for s in range(1, a.total_iterations + 1) if a.schedule.densifies(s, every)]
        self.prune_steps = rounds[config.prune_every - 1::config.prune_every]
        self.history: list[dict[str, float]] = []
        self.seconds = 0.0

    @property
    def train_seconds(self) -> float:
        """Seconds both trainers spent training, summed over resumed sessions."""
        return self.a.train_seconds + self.b.train_seconds

    def _co_prune(self) -> None:
        tic = time.perf_counter()
        counts = co_prune(self.a, self.b, self.config.prune_distance)
        seconds = time.perf_counter() - tic
        self.seconds += seconds
        self.history.append({"step": self.a.step_count, **counts, "seconds": seconds})
        log.info("co-pruning at step %d: %d Gaussians of field A, %d of field B", self.a.step_count,
                 counts["pruned_a"], counts["pruned_b"])

    def train(self) -> None:
        """Train both fields to the end, co-pruning at ``prune_steps``."""
        a, b = self.a, self.b
        for target in [s for s in self.prune_steps if s > a.step_count] + [a.total_iterations]:
            if target > a.step_count:
                a.train(target - a.step_count)
                b.train(target - b.step_count)
            if target in self.prune_steps:
                self._co_prune()

    def resume(self) -> bool:
        """Load the newest step both fields have a checkpoint of (and repeat its co-pruning when it
        is a co-pruning step); without one, delete both fields' checkpoints and start over.
        Returns whether a checkpoint was loaded."""
        a, b = self.a, self.b
        if a.run_dir is None or b.run_dir is None:
            return False
        found = {}
        for t in (a, b):
            remove_partial_checkpoints(t.run_dir, t.stage)
            found[t] = {int(p.stem.split("_")[1]): p for p in list_checkpoints(t.run_dir, t.stage)}
        common = sorted(set(found[a]) & set(found[b]))
        if not common:
            for t in (a, b):
                for path in found[t].values():
                    path.unlink(missing_ok=True)
            return False
        step = common[-1]
        for t in (a, b):
            t.load_state_dict(read_checkpoint(found[t][step]), source=str(found[t][step]))
        log.info("resumed both stage-1 fields from step %d", step)
        if step in self.prune_steps:
            self._co_prune()
        return True


__all__ = ["CoFields", "co_prune", "prune_trainer", "twin_trainer", "unsupported", "TWIN_SEED_OFFSET", "TWIN_DIR", "TWIN_NAME"]
