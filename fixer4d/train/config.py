"""Configuration of the trainings of a run.

``TrainingConfig`` (config section ``training``) holds what every training of a run shares:
stage 1 (STGS on the observed views), stage 2, the matched-iterations control, the self-check's
fold and the learned restorer's leave-one-out folds all train with it. ``Stage2Config`` (section
``stage2``) is what stage 2 (restoration-guided refinement) adds. Both are JSON-serializable with
``dataclasses.asdict`` and echoed into the run folder's config.json. Learning rates follow STGS/3DGS (values per Adam step; "x extent" means the
value is multiplied by the scene extent, so a scene in metres and the same scene in millimetres
train identically).
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

from fixer4d.errors import InputError
from fixer4d.geometry.subsample import INIT_SUBSAMPLES
from fixer4d.restore.visibility import VisibilityConfig
from fixer4d.train.background import MEAN, check_background
from fixer4d.train.depth_prior import DepthPriorConfig
from fixer4d.train.device import DEVICES
from fixer4d.train.opacity_decay import OpacityDecayConfig
from fixer4d.train.scale_ratio import AGAINST as SCALE_RATIO_AGAINST

# Stage2Config.pseudo_mask values: where the pseudo-loss acts.
PSEUDO_MASKS = ("unobserved", "all")
# Stage2Config.pseudo_target values: what a cached pseudo-view frame holds.
PSEUDO_TARGETS = ("restored", "gated")
# Stage2Config.densify_stats values: whose screen-space gradients decide where stage 2 densifies.
DENSIFY_STATS = ("all", "observed", "evidence")

# 3DGS trains 30k iterations and densifies from 500 to 15k every 100, resetting opacities every
# 3000; ``TrainingConfig.for_iterations`` scales that schedule to shorter runs.
_REFERENCE_ITERATIONS = 30_000
_REFERENCE_DENSIFY_FROM = 500
# Densify no more often than every 10 steps (the gradient statistics need a few views per
# Gaussian) and no less often than every 100 (the 3DGS interval).
_MIN_DENSIFY_EVERY = 10
_MAX_DENSIFY_EVERY = 100
# Densification needs about 30 rounds over a run to grow a model from a sparse init.
_DENSIFY_ROUNDS = 30
# An opacity reset drops every opacity to 0.01; climbing back to ~0.9 takes ~130 Adam steps at
# lr_opacity 0.05 (logit -4.6 -> +2.2), and a reset must leave time for densification after it,
# so resets are never closer than this (3DGS: every 3000 of 30k). Short runs get none.
_MIN_RESET_INTERVAL = 500
# the keys TrainingConfig.for_iterations derives from the iteration count
SCHEDULE_KEYS = ("densify_every", "densify_from", "densify_until", "opacity_reset_every", "checkpoint_every")


FRAME_ORDERS = ("iid", "shuffled")


@dataclass
class TrainingConfig:
    """Spacetime Gaussians optimized on the observed (train) views: every training of a run.

    Each iteration draws one frame and ``views_per_step`` distinct train views and sums their
    L_STG = 0.8 L1 + 0.2 D-SSIM losses (stage 2 adds its pseudo-views, ``Stage2Config``).
    """

    # Sized so that the demo (three stage-1 trainings, two restoration rounds, six evaluations)
    # ends within 10 minutes on 2 idle CPU cores; raise it for quality. The schedule keys below
    # are TrainingConfig.for_iterations(1500)'s (a test keeps them in step). The figures behind this
    # default and the Gaussian budget: docs/decisions/stage1-defaults.md, stage1-budget.md.
    iterations: int = 1500
    seed: int = 0
    backend: str = "auto"
    # Where the trainer optimizes (fixer4d.train.device): "auto" takes CUDA when it and gsplat are
    # there, else the CPU; "cpu" or "cuda" insist. The device trained on is part of a result's
    # provenance (CUDA and the CPU give other last digits): the report and every checkpoint record
    # it, a checkpoint resumes on its own device only, and a stage trained on CUDA has its own
    # stage key (pipeline.keys.training_settings).
    device: str = "auto"
    views_per_step: int = 2
    # Which frame each step trains on: "iid" draws it uniformly at random; "shuffled" visits
    # every frame once per pass over the clip, in a random order drawn from (seed, pass) (3DGS's
    # camera stack), so every frame gets the same share of the steps and a resumed run draws
    # the same frames without extra state.
    frame_order: str = "iid"
    # What a render shows where no Gaussian covers a pixel: 3 numbers in [0, 1], or "mean", the
    # train views' mean colour (train/background.py; over black, +3 dB on Panoptic's validation
    # cameras, docs/decisions/background.md)
    background: tuple[float, float, float] | str = MEAN

    # -- initialization -------------------------------------------------------------------
    # Cap on the points taken from all per-frame clouds; CPU rendering cost grows with the
    # Gaussian count.
    init_max_points: int = 15_000
    # How the capped points are chosen (fixer4d.geometry.subsample): "random", a uniform draw
    # with the seed; "stratified", one seeded draw from each of k runs of the points in Z-order
    # (the density kept to within a point per region); "spatial", one point per cell of an even
    # grid, the same for every seed.
    init_subsample: str = "random"
    init_opacity: float = 0.1
    # Hard cap on the model size during densification: ~0.7 Gaussian per pixel of one 200x150
    # view; a larger budget fits the train views better and generalizes worse at 1500 iterations
    # (docs/decisions/stage1-budget.md).
    max_gaussians: int = 20_000
    # Stage 1 trains this many fields from the same init with other seeds (the init's subsample
    # draw and the training's draws) and merges them into one model (train.fields): stage 1 is
    # chaotic in its seed, and the merged model keeps what the fields agree on at full strength
    # and what one guessed at 1/fields. Each field has the budget above; stage 2 and the matched
    # control get fields x the budget. 2 against 1 on the validation cameras, paired over seeds
    # 0-4: docs/decisions/two-fields.md. 4 gains 0.11-0.22 dB more on them but takes `make run`
    # to 9.5 of its 10 minutes (docs/decisions/field-workers.md).
    fields: int = 2
    # Fields trained side by side, each in a worker process (train.field_workers): 0 = one per
    # usable CPU, 1 = one after the other in the run's process. The digits are the same either way
    # (a run's torch computes on one thread: fixer4d/threads.py, docs/decisions/field-workers.md).
    field_workers: int = 0

    # -- observed loss ---------------------------------------------------------------------
    # Extra per-pixel weight of L_STG on the pixels each train camera's own moving-content mask
    # marks (fixer4d.init.masks; w = 1 + this there, 1 elsewhere). Moving content is a few to
    # ~15 % of a static rig's pixels, so with uniform weights the static world dominates every
    # gradient, and time-local Gaussians each see only the frames near their own time. 4 gives
    # Panoptic's people (~12 % of the train pixels) ~40 % of the loss; measured:
    # Panoptic stage 1 psnr_dynamic 15.9 -> 17.8 dB and static 20.7 -> 21.6 dB, demo unchanged
    # overall and +0.6 dB on its moving pixels (docs/dynamic.md at commit 9fd7044; the validation
    # runs: docs/decisions/stage1-defaults.md). 0 = the plain L_STG.
    moving_loss_weight: float = 4.0
    # PhysGaussian's anisotropy term (train.scale_ratio) with this weight beside L_STG, on every
    # Gaussian whose longest axis is more than scale_ratio_max x its shortest; 0 = off
    # (docs/decisions/scale-ratio.md). At 10 : 1 a Gaussian a few pixels wide renders as a line.
    scale_ratio_weight: float = 0.0
    scale_ratio_max: float = 10.0
    # the axis the longest is measured against: "shortest" (PhysGaussian; flat discs pay too) or
    # "middle" (needles only)
    scale_ratio_against: str = "shortest"

    # -- learning rates (STGS "lite" values) ------------------------------------------------
    # positions: 1.6e-4 -> 1.6e-6 x extent, exponential decay over the run (3DGS/STGS).
    lr_means_init: float = 1.6e-4
    lr_means_final: float = 1.6e-6
    # log-scales and quaternions: 3DGS values (5e-3, 1e-3).
    lr_scales: float = 5e-3
    lr_quats: float = 1e-3
    # opacity logits: 3DGS 5e-2 (opacity must move fast from the 0.1 init).
    lr_opacity: float = 5e-2
    # SH DC colour: 3DGS feature lr 2.5e-3; the higher SH bands use 1/20 of it (3DGS).
    lr_colors: float = 2.5e-3
    lr_sh_rest: float = 1.25e-4
    # temporal centre (t in [0, 1)): STGS trbfc_lr 1e-4 keeps a Gaussian at its frame;
    # temporal log-scale: STGS trbfs_lr 3e-2 lets lifetimes grow or shrink quickly.
    lr_t_center: float = 1e-4
    lr_t_log_scale: float = 3e-2
    # polynomial motion: STGS uses 0.5 * movelr(3.5) * position lr = 1.75 x the position rate
    # (x extent), decayed with it; motion coefficients multiply dt <= 1 so they need the larger
    # step to follow a moving object.
    lr_motion_factor: float = 1.75
    # angular velocity of the quaternion: STGS omega_lr 1e-4.
    lr_omega: float = 1e-4

    # -- densification (3DGS, with every size relative to the scene extent) -----------------
    densify_from: int = 50
    densify_until: int = 750
    densify_every: int = 50
    # accumulated view-space gradient (NDC units, as 3DGS) above which a Gaussian is cloned/split
    densify_grad_threshold: float = 2e-4
    # max scale <= percent_dense x extent: clone; larger: split into 2 children with scale / 1.6
    percent_dense: float = 0.01
    split_children: int = 2
    split_scale_divisor: float = 1.6
    # prune: base opacity below this (3DGS 0.005) ...
    prune_opacity: float = 0.005
    # ... and, when set, after the first opacity reset: a world-space max scale above this
    # fraction of the extent (3DGS 0.1) or a screen radius above this fraction of the image's
    # larger side (3DGS 20 px of ~1000 px = 2%; gsplat's default leaves the screen test off).
    # Both off: the schedule squeezes 3DGS's 30k iterations into ~1500, so after the reset at n/4
    # only ~4 densification rounds remain, and the large Gaussians these tests delete (the far
    # dome wall and floor of a Panoptic split) leave holes that nothing nearby can refill. 1500
    # iterations, both tests at 0.1 vs off: Panoptic split c stage 1 19.01 -> 22.59 dB (seed 1
    # with the tests: 18.83), shared split 23.79 -> 23.99, demo 25.03 -> 24.74 (mean of 3 seeds;
    # LPIPS 0.081 -> 0.064); docs/decisions/stage1-defaults.md.
    prune_world_scale: float | None = None
    prune_screen_fraction: float | None = None
    opacity_reset_every: int = 500
    # opacities are clamped to at most this at a reset (3DGS 0.01)
    opacity_reset_value: float = 0.01
    # learned decay of the visible opacities in place of the resets (train.opacity_decay; off)
    opacity_decay: OpacityDecayConfig = field(default_factory=OpacityDecayConfig)
    # the init's points as a depth target of stage 1's train views (train.depth_prior; off)
    depth_prior: DepthPriorConfig = field(default_factory=DepthPriorConfig)

    # -- bookkeeping ------------------------------------------------------------------------
    checkpoint_every: int = 375
    keep_checkpoints: int = 2
    progress: bool = True

    def __post_init__(self) -> None:
        self.background = check_background(self.background)  # type: ignore[assignment]
        if isinstance(self.opacity_decay, dict):
            self.opacity_decay = OpacityDecayConfig(**_known(OpacityDecayConfig, self.opacity_decay))
        if isinstance(self.depth_prior, dict):
            self.depth_prior = DepthPriorConfig(**_known(DepthPriorConfig, self.depth_prior))
        if self.iterations < 0:
            raise InputError(f"TrainingConfig.iterations must be >= 0, got {self.iterations}")
        if self.device not in DEVICES:
            raise InputError(f"TrainingConfig.device {self.device!r}: choose one of {list(DEVICES)}")
        if self.init_subsample not in INIT_SUBSAMPLES:
            raise InputError(f"TrainingConfig.init_subsample {self.init_subsample!r}: choose one of "
                             f"{list(INIT_SUBSAMPLES)}")
        if self.frame_order not in FRAME_ORDERS:
            raise InputError(f"TrainingConfig.frame_order {self.frame_order!r}: choose one of {list(FRAME_ORDERS)}")
        if self.views_per_step < 1:
            raise InputError(f"TrainingConfig.views_per_step must be >= 1, got {self.views_per_step}")
        if self.densify_every < 1 or self.checkpoint_every < 1 or self.opacity_reset_every < 1:
            raise InputError("TrainingConfig: densify_every, checkpoint_every and opacity_reset_every must be >= 1")
        if not self.scale_ratio_weight >= 0.0 or not self.scale_ratio_max >= 1.0:
            raise InputError(f"TrainingConfig: scale_ratio_weight must be >= 0 (0 = off) and scale_ratio_max >= 1, "
                             f"got {self.scale_ratio_weight} and {self.scale_ratio_max}")
        if self.scale_ratio_against not in SCALE_RATIO_AGAINST:
            raise InputError(f"TrainingConfig.scale_ratio_against {self.scale_ratio_against!r}: choose one of "
                             f"{list(SCALE_RATIO_AGAINST)}")
        if self.moving_loss_weight < 0:
            raise InputError(f"TrainingConfig.moving_loss_weight must be >= 0, got {self.moving_loss_weight}")
        if self.fields < 1:
            raise InputError(f"TrainingConfig.fields must be >= 1, got {self.fields}")
        if self.field_workers < 0:
            raise InputError(f"TrainingConfig.field_workers must be >= 0 (0: one per CPU), got {self.field_workers}")
        if self.max_gaussians < 1 or self.init_max_points < 1:
            raise InputError("TrainingConfig: max_gaussians and init_max_points must be >= 1")
        for name in ("prune_world_scale", "prune_screen_fraction"):
            value = getattr(self, name)
            if value is not None and not value > 0:
                raise InputError(f"TrainingConfig.{name} must be > 0 or null (off), got {value}")

    @classmethod
    def for_iterations(cls, iterations: int, **overrides: Any) -> "TrainingConfig":
        """A config whose densification/reset schedule is the 3DGS 30k schedule scaled to
        ``iterations`` (densify from ~1/60 to 1/2 of the run, ~30 rounds, one opacity reset at a
        quarter when the run is long enough to recover from it); explicit ``overrides`` win."""
        n = max(int(iterations), 1)
        every = min(max(n // _DENSIFY_ROUNDS, _MIN_DENSIFY_EVERY), _MAX_DENSIFY_EVERY)
        sched = dict(
            iterations=int(iterations),
            densify_every=every,
            densify_from=max(every, n * _REFERENCE_DENSIFY_FROM // _REFERENCE_ITERATIONS),
            densify_until=n // 2,
            opacity_reset_every=max(n // 4, _MIN_RESET_INTERVAL),
            checkpoint_every=max(min(500, n // 4), 1),
        )
        sched.update(overrides)
        return cls(**sched)

    @classmethod
    def rescheduled(cls, training: dict[str, Any], iterations: int) -> dict[str, Any]:
        """``training`` (a config tree section whose schedule may be written out, as in a run's
        config.json) with its iteration count set to ``iterations``: every schedule key that
        still holds the value derived from the old count is derived again from the new one; a
        key the user set to something else is kept."""
        out = dict(training)
        old = out.get("iterations", cls.iterations)
        out["iterations"] = int(iterations)
        derived_old = cls.for_iterations(old).to_dict()
        derived_new = cls.for_iterations(iterations).to_dict()
        for key in SCHEDULE_KEYS:
            if key in out and out[key] == derived_old[key]:
                out[key] = derived_new[key]
        return out

    @classmethod
    def from_partial(cls, **given: Any) -> "TrainingConfig":
        """The config a run asks for: the schedule scaled to the given iterations (default
        ``TrainingConfig.iterations``) unless the schedule keys themselves are given."""
        iterations = given.pop("iterations", cls.iterations)
        return cls.for_iterations(iterations, **given)

    def to_dict(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        d["background"] = self.background if isinstance(self.background, str) else list(self.background)
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "TrainingConfig":
        return cls(**_known(cls, d))


# Stage2Config fields added after runs existed, with the behaviour those runs had (``keyed``)
STAGE2_SETTINGS_BEFORE = (("restore_holes", True), ("fields", "merged"))
# How stage 2 and the matched control continue a stage 1 of several fields (``training.fields``):
# "merged" trains the merged model, "apart" trains each field on its own and merges after.
STAGE2_FIELDS = ("merged", "apart")


@dataclass
class Stage2Config:
    """Stage 2: L = L_STG(observed views) + lambda_gen * L1(render at a pseudo-view, cached target).

    The cache is refreshed (the pipeline renders the trajectories with the current model and
    restores them) at step 0 and every ``refresh_every`` steps, ``rounds`` times in all; after the
    last round training continues on the last cache until ``iterations`` (default: rounds x
    refresh_every).
    """

    lambda_gen: float = 0.5
    refresh_every: int = 150
    rounds: int = 2
    iterations: int | None = None
    # cached frames per iteration (each one a pseudo-view render + L1). With ground-truth
    # pseudo-targets (benchmarks/stage2_ceiling.py, demo, 1500-iteration stage 1) 2 would pay: Full
    # over the matched control +0.53 / +0.75 dB with 1, +0.85 / +1.36 dB with 2 (two stage-1
    # models); with the warp restorer's targets it does not (Full 24.58 -> 24.85 on one model,
    # 25.32 -> 25.11 on the other), so the cheaper 1 stays until a restorer gets closer to the truth.
    batch_pseudo: int = 1
    # weight the pseudo L1 per pixel by the restorer's confidence (masked L1)
    confidence_weighting: bool = True
    # positions continue from near the end of stage 1's decay: the geometry is mostly settled
    # and the pseudo-targets are less reliable than real views.
    lr_means_init: float = 1.6e-5
    lr_means_final: float = 1.6e-6
    # densification keeps running in stage 2 (pseudo-views expose holes) until this fraction
    # of the stage-2 iterations; 0 disables it.
    densify_until_fraction: float = 0.5
    # Whose gradients feed the densification statistics: "all" every render of a step, the
    # observed views' and the pseudo-views' (the paper); "observed" the observed views only;
    # "evidence" the observed views plus the pseudo-views' gradient of their loss restricted to
    # the pixels no train camera explains (restore.visibility), so that a pseudo-target can grow
    # the model only where no real view already decides it. Chosen on the validation cameras
    # (docs/decisions/stage2-targets.md): with gated targets, Full - STGS w/ MVS on Panoptic 4/14, split c 2/12 and
    # demo_val +0.11 / +0.48 / +0.03 dB (evidence) against +0.17 / +0.39 / +0.01 (all).
    densify_stats: str = "evidence"
    # restored clips held decoded in memory (each is F frames of H x W x 3 float32)
    max_cached_clips: int = 8
    seed: int = 0
    # Where the pseudo-loss acts: "all" supervises every pixel (the paper's stage 2);
    # "unobserved" weights each pseudo pixel by how little the train cameras explain it
    # (restore.visibility: holes and surfaces no train camera sees near the novel ray get the full
    # weight, observed ones ``observed_weight``). Chosen on the validation cameras (Panoptic 4/14
    # and split c 2/12, Full): all 18.88 / 18.69, observed_weight 0.25 18.30 / 19.07, unobserved
    # only 18.49 / 18.47; "all" has the best mean and the best worst case
    # (docs/decisions/pseudo-loss-mask.md).
    pseudo_mask: str = "all"
    observed_weight: float = 0.0
    # What a pseudo-view frame asks the model to render: "restored" the restorer's output, weighted
    # by its confidence (the paper); "gated" the restored frame where the train cameras leave a
    # pixel unobserved and the restorer is confident (``pipeline.restoration.gate_restoration``),
    # the fallback (``fill_unobserved``) elsewhere, every pixel at weight 1: observed pixels of a
    # novel view are held where they were at the last refresh (a proximal anchor against the drift
    # that more training on four views causes), and only unobserved ones move. Chosen on the validation cameras
    # (docs/decisions/stage2-targets.md), Full - STGS w/ MVS on Panoptic 4/14, split c 2/12, demo_val: restored
    # +0.22 / -0.05 / +0.12 dB, gated +0.11 / +0.48 / +0.03 (both with evidence densification
    # for gated, the paper's for restored); against the matched control restored loses up to
    # 0.38 dB, gated at most 0.20.
    pseudo_target: str = "gated"
    # The gated targets' fallback where the restorer does not act: true, the render with its
    # unobserved pixels filled from the observed ones (restore.unobserved_fill, as the Restoration
    # rows); false, the render of the refresh. Chosen on the validation cameras over the mean-colour
    # background, stage 2 forced, paired against false over seeds 0-2: Panoptic 4/14 +0.20 dB, split
    # c 2/12 +0.56 (false without the hole rule: +0.25 / +0.38; docs/decisions/unobserved-fill.md).
    fill_unobserved: bool = True
    # With the render as the gated targets' fallback: a hole (alpha under
    # ``visibility.hole_alpha_low``..``high``) takes the restored frame whatever the restorer's
    # confidence (true), or only by confidence x unobserved like any unseen pixel (false).
    restore_holes: bool = True
    # With ``training.fields`` > 1: "merged" continues the merged model (one training, the fields'
    # budgets summed); "apart" continues each field with its own seeds and budget and merges the
    # refined fields (train/fields.py), so that training after the merge cannot undo the
    # averaging of the fields' independent errors. "merged": apart lost 0.23 dB to it on demo_val
    # at each of seeds 0-2, gaining 0.1-0.3 on the real splits' at three of four
    # (docs/decisions/stage2-two-fields.md).
    fields: str = "merged"
    visibility: VisibilityConfig = field(default_factory=VisibilityConfig)

    def __post_init__(self) -> None:
        if self.pseudo_mask not in PSEUDO_MASKS:
            raise InputError(f"Stage2Config.pseudo_mask must be one of {', '.join(PSEUDO_MASKS)}, got {self.pseudo_mask!r}")
        if self.pseudo_target not in PSEUDO_TARGETS:
            raise InputError(f"Stage2Config.pseudo_target must be one of {', '.join(PSEUDO_TARGETS)}, "
                             f"got {self.pseudo_target!r}")
        if self.densify_stats not in DENSIFY_STATS:
            raise InputError(f"Stage2Config.densify_stats must be one of {', '.join(DENSIFY_STATS)}, "
                             f"got {self.densify_stats!r}")
        if self.fields not in STAGE2_FIELDS:
            raise InputError(f"Stage2Config.fields must be one of {', '.join(STAGE2_FIELDS)}, got {self.fields!r}")
        if not 0.0 <= self.observed_weight <= 1.0:
            raise InputError(f"Stage2Config.observed_weight must be in [0, 1], got {self.observed_weight}")
        if isinstance(self.visibility, dict):
            self.visibility = VisibilityConfig(**self.visibility)
        if self.refresh_every < 1 or self.rounds < 0 or self.batch_pseudo < 0:
            raise InputError("Stage2Config: refresh_every must be >= 1, rounds and batch_pseudo >= 0 "
                             "(rounds = 0: no stage 2)")
        if self.lambda_gen < 0:
            raise InputError(f"Stage2Config.lambda_gen must be >= 0, got {self.lambda_gen}")

    @property
    def total_iterations(self) -> int:
        return int(self.iterations) if self.iterations is not None else self.rounds * self.refresh_every

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def keyed(self) -> dict[str, Any]:
        """The settings as stage keys and checkpoints record them: a setting at the value every
        stage 2 had before it existed is left out, so those runs keep their keys."""
        d = self.to_dict()
        for name, before in STAGE2_SETTINGS_BEFORE:
            if d.get(name) == before:
                d.pop(name)
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "Stage2Config":
        return cls(**_known(cls, d))


def matched_config(training: TrainingConfig, stage2: Stage2Config) -> TrainingConfig:
    """The TrainingConfig of the matched-iterations control: ``training`` continued for stage 2's
    length with stage 2's learning rates, densification window and seed, and no opacity reset
    (stage 2 without pseudo-views), and no opacity decay either."""
    n = stage2.total_iterations
    until = int(stage2.densify_until_fraction * n)
    return dataclasses.replace(training, iterations=n, lr_means_init=stage2.lr_means_init,
                               lr_means_final=stage2.lr_means_final, densify_from=min(training.densify_every, until),
                               densify_until=until, opacity_reset_every=n + 1, seed=stage2.seed,
                               opacity_decay=OpacityDecayConfig(enabled=False))


def _known(cls: type, d: dict[str, Any]) -> dict[str, Any]:
    names = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(d) - names)
    if unknown:
        raise InputError(f"{cls.__name__}: unknown keys {unknown} in the config; remove them or update fixer4d")
    out = dict(d)
    if "background" in out and not isinstance(out["background"], str):
        out["background"] = tuple(out["background"])
    return out


__all__ = ["TrainingConfig", "Stage2Config", "matched_config"]


def __getattr__(name: str) -> Any:
    if name == "Stage1Config":  # the deprecation alias: the name before TrainingConfig
        import warnings

        warnings.warn("fixer4d.train.config.Stage1Config is now TrainingConfig", DeprecationWarning, stacklevel=2)
        return TrainingConfig
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
