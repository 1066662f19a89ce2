"""Stage 2's self-check: does pseudo-supervision help on this scene? Asked of a train camera.

A held-out camera may never decide anything, yet stage 2 can lower a real capture's quality
(pseudo-targets that contradict the real views; more training on four views that already
overfits). So the run asks one of its own train cameras, held back:

1. a fold: the scene seen through the other train cameras only (``TrainOnlyView`` at
   ``scale``), its own init from those cameras, stage 1 on them (the run's stage-1 settings);
2. from that model, *refine* (stage 2 as configured: the run's restorer, trajectories between
   the fold's cameras, pseudo-loss) and, with ``allow_continue``, *continue* (as much more
   stage-1 training, no pseudo-views: the matched-iterations control);
3. the held-back camera's PSNR before (*skip*: no more training) and after each continuation,
   on ``eval_frames`` frames spread over the clip.

With ``cameras`` > 1 the check runs one such fold per held-back camera (train cameras ``fold``,
``fold + 1``, ... in turn, each fold trained on the others) and each candidate's figure is the
mean over the folds; the unit of the paired gains is then the fold (its mean over the scored
frames), since the frames of one camera move together and only other cameras tell how a gain
varies over the scene.

The decision is the best of the candidates if it beats *skip* by more than its margin, else
*skip*: ``tie_db`` (the fold's own noise) or, with ``margin = "measured"``, the larger of ``tie_db``
and the 95 % half-width of the candidate's paired gain over *skip* (per fold, or per scored frame
when there is one fold). Every record
holds the per-frame figures and each candidate's gain ± standard error, so a finished fold can
be decided again under either rule without training; and the run's final model follows it: *refine* runs stage 2,
*continue* keeps the matched-iterations control, *skip* keeps the stage-1 model, so the final
model leaves the stage-1 model only for one that raised the held-back camera by more than the
fold can resolve. Its figures and
seconds go into the report. The held-back camera's frames reach nothing the fold uses: the fold's
stages read a view of its own cameras only (the held-back camera is read only to score it), and a
learned restorer is trained again inside the fold, from the fold's cameras, init and model (the
run's restorer learned from every train camera), so the check does not see its own answer.

This module holds the settings and the rule; ``self_check_run.run_self_check`` runs the fold.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

from fixer4d.errors import InputError
from fixer4d.stats import paired_gain, student_t_quantile

CHOICES = ("skip", "continue", "refine")
MARGINS = ("fixed", "measured")
DECISION_FILE = "decision.json"


@dataclass
class SelfCheckConfig:
    """The stage-2 self-check (module docstring).

    enabled: run it (False: stage 2 always runs, as in the paper).
    fold: index into the scene's train cameras of the one held back (taken modulo their count);
      3 is the learned restorer's validation fold (``restorer.learned.validation_fold``), the
      camera whose frames that restorer never learns from.
    scale: resolution of the fold's trainings (0.5: a quarter of the pixels, ~4x cheaper).
    eval_frames: frames of the held-back camera scored, spread over the clip.
    tie_db: the best candidate is taken only if it beats the baseline (skip) by more than this.
      0.1 dB is the fold's own noise, measured on Panoptic's fold (docs/decisions/self-check.md):
      its held-back camera moves by about 0.1 dB from one quarter of stage 2's length to the next,
      as much as a real difference it would have to tell.
    allow_skip: "skip" (no training after stage 1) is a candidate (False, which needs
      ``allow_continue``: the check only asks whether pseudo-views pay against the same amount of
      plain training). On: a stage that may not lower the deliverable keeps the stage-1 model
      unless the fold shows a gain beyond its noise; on the validation runs
      (docs/decisions/self-check.md) it decides one of five differently, the demo's, whose fold
      gained 0.07 dB.
    allow_continue: "continue" (the matched-iterations control) is a candidate, trained in the
      fold. Off: the check chooses between skip and refine and the fold does not train it. Over
      30 quality-bench runs the fold's continue − skip did not predict the held-out cameras' (sign
      agreement 50 %, correlation −0.10), and without it the validation cameras gained +0.07 ±
      0.12 dB over the 15 runs of the default (docs/decisions/self-check.md). A decision setting:
      switching it decides again from a finished fold (training only continue, if it is missing).
    margin: "fixed" (``tie_db``) or "measured" (the larger of ``tie_db`` and the 95 % half-width
      of the best candidate's paired gain over the baseline, per fold or per frame). "fixed" until
      the quality bench's seeds decide between them on validation cameras
      (docs/decisions/self-check.md).
    cameras: train cameras held back in turn, one fold each (module docstring); at most the number
      of train cameras.
    scale_budget: the fold's init points and Gaussian cap scale with its pixels (x ``scale`` ^ 2),
      so a fold holds as many Gaussians per pixel as the run. With the run's whole budget a fold at
      scale 0.5 costs 60-80 % of the run's stage 1 (the per-Gaussian work does not shrink with the
      image) and the check took 29-43 % of a run; scaled, a Panoptic fold takes 0.44-0.48x the
      CPU, and it decided as the unscaled fold in 11 of 12 runs (docs/decisions/self-check.md).
    fields: the most fields the fold's stage 1 merges (``fold_fields``; the run's
      ``training.fields`` when fewer; 0: all of the run's, as every fold before the setting). 2:
      over the quality bench's 15 runs of four fields (5 seeds of the demo and both Panoptic
      splits) a two-field fold decided as a four-field one in all 15 (skip; refine − skip −0.55
      against −0.84 dB on average) at half the fold's training (docs/decisions/field-workers.md).
    """

    enabled: bool = True
    fold: int = 3
    scale: float = 0.5
    eval_frames: int = 6
    tie_db: float = 0.1
    allow_skip: bool = True
    allow_continue: bool = False
    margin: str = "fixed"
    cameras: int = 1
    scale_budget: bool = True
    fields: int = 2

    def __post_init__(self) -> None:
        if not 0.0 < self.scale <= 1.0:
            raise InputError(f"self_check.scale must be in (0, 1], got {self.scale}")
        if self.margin not in MARGINS:
            raise InputError(f"self_check.margin must be one of {', '.join(MARGINS)}, got {self.margin!r}")
        if self.eval_frames < 1 or self.fold < 0 or self.tie_db < 0 or self.cameras < 1 or self.fields < 0:
            raise InputError("self_check: eval_frames >= 1, fold >= 0, tie_db >= 0, cameras >= 1 and fields >= 0 "
                             "are needed")
        if not (self.allow_skip or self.allow_continue):
            raise InputError("self_check: allow_skip and allow_continue are both off, which leaves refine alone; "
                             "set self_check.enabled=false to always run stage 2")

    def candidates(self) -> tuple[str, ...]:
        """The candidates the fold trains and scores (skip is always scored: it is the fold's model)."""
        return tuple(c for c in CHOICES if c != "continue" or self.allow_continue)

    def fold_training(self, training):
        """The fold's TrainingConfig from the run's ``training`` (``scale_budget``)."""
        import dataclasses

        if not self.scale_budget:
            return training
        share = self.scale ** 2
        return dataclasses.replace(training, max_gaussians=max(1, round(training.max_gaussians * share)),
                                   init_max_points=max(1, round(training.init_max_points * share)))

    def held_back(self, train_ids: Sequence[int]) -> list[int]:
        """The train cameras held back, one fold each: ``cameras`` of ``train_ids`` from ``fold`` on
        (cyclically, at most all of them)."""
        n = len(train_ids)
        return [int(train_ids[(self.fold + k) % n]) for k in range(min(self.cameras, n))]


def fold_fields(config) -> int:
    """How many fields the fold's stage 1 trains: the run's ``training.fields``, at most
    ``self_check.fields`` (0: no limit), merged, when stage 2 continues the merged model; one when
    it continues each field apart (``stage2.fields=apart``), since the run then refines every field
    as one field's model, which is what one field's fold checks, at half the fold's training."""
    from fixer4d.train.fields import refined_apart

    if refined_apart(config.training, config.stage2):
        return 1
    return min(config.training.fields, config.self_check.fields or config.training.fields)


def gains(frames: dict[str, Sequence[float]], baseline: str = "skip") -> dict[str, dict[str, float | None]]:
    """{candidate: {"gain_db", "se_db"}}: each other candidate's paired gain over ``baseline``
    (``frames``: candidate -> PSNR per unit, dB: per scored frame of one fold, or per fold), mean
    and standard error."""
    out = {}
    for c, values in frames.items():
        if c != baseline and baseline in frames:
            mean, se = paired_gain(values, frames[baseline])
            out[c] = {"gain_db": mean, "se_db": se}
    return out


def margin_db(tie_db: float, margin: str, candidate: Sequence[float] | None, baseline: Sequence[float] | None) -> float:
    """How much a candidate must beat the baseline by: ``tie_db``, or under "measured" the larger of
    ``tie_db`` and the 95 % half-width (Student t) of its per-frame paired gain."""
    if margin == "fixed" or not candidate or not baseline or len(candidate) < 2:
        return tie_db
    _, se = paired_gain(candidate, baseline)
    return max(tie_db, student_t_quantile(0.975, len(candidate) - 1) * (se or 0.0))


def decide(psnr: dict[str, float], tie_db: float, allow_skip: bool = True, margin: str = "fixed",
           frames: dict[str, Sequence[float]] | None = None) -> str:
    """The choice of ``psnr`` ({"skip", "continue", "refine"} -> dB): the best candidate (exact
    ties to the simpler), taken only if it beats the simplest candidate, the baseline, by more than
    its margin (``margin_db``; ``frames``: the per-frame PSNRs the means come from, needed by the
    "measured" margin); otherwise the baseline. The baseline is skip, or continue without
    ``allow_skip`` (then the candidates are continue and refine)."""
    candidates = [c for c in CHOICES if c in psnr and (allow_skip or c != "skip")]
    if not candidates:
        raise InputError(f"self-check: no PSNR of a candidate ({', '.join(CHOICES)}) to decide from, got {sorted(psnr)}")
    baseline = candidates[0]
    best = max(candidates, key=lambda c: (psnr[c], -candidates.index(c)))
    frames = frames or {}
    need = margin_db(tie_db, margin, frames.get(best), frames.get(baseline))
    return best if psnr[best] > psnr[baseline] + need else baseline


__all__ = ["SelfCheckConfig", "decide", "gains", "margin_db", "CHOICES", "MARGINS", "DECISION_FILE"]
