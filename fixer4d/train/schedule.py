"""Schedules of a training stage: the position learning rate (a pure function of the step, so a
resumed run gets the same rates) and ``StageSchedule``, what differs between stage 1 and stage 2."""
from __future__ import annotations

import math
from dataclasses import dataclass

from fixer4d.train.config import TrainingConfig, Stage2Config


def exponential_lr(step: int, lr_init: float, lr_final: float, max_steps: int) -> float:
    """Log-linear interpolation from ``lr_init`` at step 0 to ``lr_final`` at ``max_steps``.

    The position schedule of 3DGS/STGS: the learning rate decays by a constant factor per step;
    steps beyond ``max_steps`` keep ``lr_final``. A zero rate at either end gives 0 throughout
    (a frozen parameter).
    """
    if lr_init <= 0.0 or lr_final <= 0.0:
        return 0.0
    if max_steps <= 0:
        return float(lr_final)
    s = min(max(step / float(max_steps), 0.0), 1.0)
    return float(math.exp((1.0 - s) * math.log(lr_init) + s * math.log(lr_final)))


@dataclass(frozen=True)
class StageSchedule:
    """The per-stage part of a training: ``StageSchedule.stage1(config)`` or
    ``StageSchedule.stage2(config, stage2)``; everything else comes from the TrainingConfig.

    stage: 1 or 2 (checkpoint names, messages). iterations: steps of the stage. seed: seed of
    the trainer's generators.
    lr_means_init / lr_means_final: position learning rate (x extent) at step 0 and at
    ``iterations``, log-linear in between.
    densify_from / densify_until: densification statistics are gathered at steps < until and
    the model is densified at (1-based) steps from < s < until.
    opacity_reset_every: steps between opacity resets (while densifying), None = none; the size
    prunes apply only after the first reset, so there are none either without resets.
    decay_from / decay_until: the (0-based) steps from <= s < until of the learned opacity decay
    (``train.opacity_decay``), which replaces the resets; decay_from None = no decay.
    revises_terms: whether an auto-mode model-terms decision is revised on the density schedule.
    lambda_gen, pseudo_batch: weight of the pseudo-view loss and cached frames per step; the
    stage draws pseudo-views when both are > 0.
    refresh_every, rounds: the restoration cache is refreshed at step 0 and every
    ``refresh_every`` steps, ``rounds`` times in all (0: never).
    densify_stats: whose gradients feed the densification statistics (``Stage2Config``):
    "all", "observed" or "evidence"; stage 1 has only observed views.
    """

    stage: int
    iterations: int
    seed: int
    lr_means_init: float
    lr_means_final: float
    densify_from: int
    densify_until: int
    opacity_reset_every: int | None
    revises_terms: bool
    decay_from: int | None = None
    decay_until: int | None = None
    lambda_gen: float = 0.0
    pseudo_batch: int = 0
    refresh_every: int = 1
    rounds: int = 0
    densify_stats: str = "all"

    @classmethod
    def stage1(cls, config: TrainingConfig) -> "StageSchedule":
        """STGS on the observed views: the TrainingConfig's schedule, opacity resets (or the opacity
        decay in their place, from its ``start`` or the first densification), no pseudo-views."""
        decay = config.opacity_decay
        decay_from = (None if not decay.enabled else config.densify_from if decay.start is None else decay.start)
        decay_until = int(math.ceil(decay.until_fraction * config.iterations))
        return cls(stage=1, iterations=config.iterations, seed=config.seed, lr_means_init=config.lr_means_init,
                   lr_means_final=config.lr_means_final, densify_from=config.densify_from,
                   densify_until=config.densify_until,
                   opacity_reset_every=None if decay.enabled else config.opacity_reset_every,
                   revises_terms=True, decay_from=decay_from, decay_until=decay_until)

    @classmethod
    def stage2(cls, config: TrainingConfig, stage2: Stage2Config) -> "StageSchedule":
        """Restoration-guided refinement: stage 2's length, position rates and seed, densification
        from the first densify round until ``densify_until_fraction`` of the stage, no opacity
        reset (the model is already shaped) and pseudo-views from the refreshed cache."""
        n = stage2.total_iterations
        until = int(stage2.densify_until_fraction * n)
        return cls(stage=2, iterations=n, seed=stage2.seed, lr_means_init=stage2.lr_means_init,
                   lr_means_final=stage2.lr_means_final, densify_from=min(config.densify_every, until),
                   densify_until=until, opacity_reset_every=None, revises_terms=False,
                   lambda_gen=stage2.lambda_gen, pseudo_batch=stage2.batch_pseudo,
                   refresh_every=stage2.refresh_every, rounds=stage2.rounds,
                   densify_stats=stage2.densify_stats)

    def position_lr(self, step: int) -> float:
        """Position learning rate at ``step`` before the extent factor."""
        return exponential_lr(step, self.lr_means_init, self.lr_means_final, self.iterations)

    @property
    def draws_pseudo_views(self) -> bool:
        return self.lambda_gen > 0 and self.pseudo_batch > 0

    def gathers_stats(self, step: int) -> bool:
        """Whether the densification statistics take the gradients of (0-based) ``step``."""
        return step < self.densify_until

    def densifies(self, step: int, every: int) -> bool:
        """Whether the model is densified after (1-based) ``step``, every ``every`` steps."""
        return self.densify_from < step < self.densify_until and step % every == 0

    def size_prunes_apply(self, step: int) -> bool:
        """Whether the size prunes apply at (1-based) ``step``: after the first opacity reset, as in
        3DGS."""
        return self.opacity_reset_every is not None and step > self.opacity_reset_every

    def resets_opacity(self, step: int) -> bool:
        """Whether opacities are reset after (1-based) ``step``."""
        return (self.opacity_reset_every is not None and step < self.densify_until
                and step % self.opacity_reset_every == 0)

    def decays(self, step: int) -> bool:
        """Whether (0-based) ``step`` decays the opacities it renders."""
        return self.decay_from is not None and self.decay_from <= step < self.decay_until

    def refresh_round(self, step: int) -> int | None:
        """The cache round refreshed before (0-based) ``step``, or None."""
        if step % self.refresh_every == 0 and step // self.refresh_every < self.rounds:
            return step // self.refresh_every
        return None
