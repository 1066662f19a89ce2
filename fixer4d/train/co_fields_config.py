"""``CoFieldsConfig``: the run's ``co_fields`` section (two stage-1 fields that check each other).

With ``enabled`` stage 1 trains a second field beside the first (``fixer4d.train.co_fields``),
co-prunes both, and saves the second as RUN/model_stage1_twin.ply; ``weight`` decides whether its
disagreement with the first (``restore.undetermined``) gates the restoration and the pseudo-loss.
Off by default (docs/decisions/co-fields.md has the figures).
"""
from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any, Literal

from fixer4d.errors import InputError

# Values of ``weight``: the per-pixel weight that gates restoration and the pseudo-loss.
WEIGHTS = ("visibility", "undetermined", "max")


@dataclass
class CoFieldsConfig:
    """enabled: train the twin field and co-prune (stage 1). prune_every: densification rounds
    between two co-prunings (CoR-GS densifies every 100 steps and co-prunes every 500: 5 rounds;
    the default schedule's 13 rounds get two co-prunings, after rounds 5 and 10).
    prune_distance: a Gaussian whose nearest Gaussian of the other field is farther than this
    fraction of the scene extent is pruned. 0.02 = twice ``training.percent_dense``: a Gaussian
    splits only once it is larger than percent_dense x extent and its children are drawn within
    about its own scale of it, so the two fields' descendants of one initial point lie within a
    few percent_dense of each other, while a floater one field grew alone in empty space does not.
    weight: "visibility" (restore.visibility's unobserved weight, as without co_fields),
    "undetermined" (the twin's render disagreement at the pseudo-view) or "max" of the two; it
    gates stage 2's pseudo-targets and the Restoration rows. The twin stays as stage 1 left it
    while stage 2 trains field A. The stage-2 self-check's fold trains no twin: its stage 2 gates
    by the visibility weight.
    """

    enabled: bool = False
    prune_every: int = 5
    prune_distance: float = 0.02
    weight: Literal["visibility", "undetermined", "max"] = "visibility"

    def __post_init__(self) -> None:
        if self.prune_every < 1:
            raise InputError(f"co_fields.prune_every must be >= 1, got {self.prune_every}")
        if not self.prune_distance > 0:
            raise InputError(f"co_fields.prune_distance must be > 0, got {self.prune_distance}")
        if self.weight not in WEIGHTS:
            raise InputError(f"co_fields.weight must be one of {', '.join(WEIGHTS)}, got {self.weight!r}")

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    def stage1_settings(self) -> dict[str, Any]:
        """The settings stage 1's result depends on (``weight`` acts in stage 2 and the rows only)."""
        return {k: v for k, v in self.to_dict().items() if k != "weight"}


__all__ = ["CoFieldsConfig", "WEIGHTS"]
