"""Which restorer stage 2 uses, with its settings: ``RestoreConfig`` (``restore.factory.build_restorer``
builds it).

    config = RestoreConfig.from_dict({"kind": "learned"})
    restorer = build_restorer(config, weights_dir=run_dir / "restorer")

Kinds (docs/design.md §11): ``learned`` (a small per-scene CNN trained leave-one-camera-out on the
scene's own train cameras, ``restore/learned.py``; needs its weights), ``warp`` (the geometric
``ReferenceWarpRestorer``) and ``cogvideo`` (CogVideoX video-to-video, GPU + local weights).
``sr_prior`` (``restore/sr_prior.py``, off by default) passes any kind's output through Real-ESRGAN
where its confidence is low. ``settings_key()`` is exactly what changes a pseudo-target, for cache
keys and reports.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

from fixer4d.errors import InputError
import fixer4d.restore.constants as C
from fixer4d.restore.cogvideo import CogVideoConfig
from fixer4d.restore.reference_warp import ReferenceWarpConfig
from fixer4d.restore.sr_prior import SRPriorConfig

KINDS = ("learned", "warp", "cogvideo")
# The learned restorer's files inside its weights folder (RUN/restorer/).
WEIGHTS_FILE = "weights.npz"
META_FILE = "restorer.json"
VALIDATION_FILE = "validation.json"


@dataclass
class LearnedRestorerConfig:
    """Settings of the learned restorer: how its training pairs are made and how it is trained.

    Pairs (``fixer4d.train.restorer_pairs``): for each train camera c, a short stage 1
    (``loo_iterations`` at ``loo_scale`` of the resolution) on the other train cameras; the
    render of c from it at ``pair_frames`` timestamps is a degraded input whose target is c's real
    frame; renders of the seen cameras at the ``early_fraction`` checkpoint are milder cases.
    Fold ``validation_fold`` (an index into the scene's train cameras) is held back and scored.
    Network (``restore/learned.py``): ``width`` base channels, ``steps`` Adam steps of ``batch``
    random ``crop`` x ``crop`` crops at learning rate ``lr``, ``threads`` torch threads, ``seed``.
    """

    loo_iterations: int = 100
    loo_scale: float = 0.5
    early_fraction: float = 0.25
    pair_frames: int = 5
    validation_fold: int = 3
    width: int = C.LEARNED_WIDTH
    residual_bound: float = C.LEARNED_RESIDUAL_BOUND
    steps: int = 400
    batch: int = 4
    crop: int = 64
    lr: float = 2e-3
    threads: int = 1
    temporal_radius: int = C.TEMPORAL_RADIUS
    temporal_neighbor_weight: float = C.TEMPORAL_NEIGHBOR_WEIGHT
    seed: int = 0

    def __post_init__(self) -> None:
        positive = ("loo_iterations", "pair_frames", "width", "steps", "batch", "crop", "threads")
        for name in positive:
            if int(getattr(self, name)) < 1:
                raise InputError(f"LearnedRestorerConfig.{name} must be >= 1, got {getattr(self, name)}")
        if not 0.0 < self.loo_scale <= 1.0:
            raise InputError(f"LearnedRestorerConfig.loo_scale must be in (0, 1], got {self.loo_scale}")
        if not 0.0 < self.early_fraction < 1.0:
            raise InputError(f"LearnedRestorerConfig.early_fraction must be in (0, 1), got {self.early_fraction}")
        if self.residual_bound < 0 or self.lr <= 0 or self.temporal_radius < 0:
            raise InputError("LearnedRestorerConfig: residual_bound >= 0, lr > 0 and temporal_radius >= 0 needed")

    def training_key(self) -> dict[str, Any]:
        """The fields that change the trained weights (everything but the inference-time smoothing)."""
        d = dataclasses.asdict(self)
        d.pop("temporal_radius")
        d.pop("temporal_neighbor_weight")
        return d


@dataclass
class RestoreConfig:
    """The restorer of a run: ``kind`` (learned | warp | cogvideo) and each kind's settings.

    The learned restorer also uses ``warp`` (its inputs are the reference warps and the warp
    restorer's output), so ``warp`` settings change its targets too. ``sr_prior`` applies to every
    kind's output when enabled.
    """

    kind: str = "warp"
    warp: ReferenceWarpConfig = field(default_factory=ReferenceWarpConfig)
    learned: LearnedRestorerConfig = field(default_factory=LearnedRestorerConfig)
    cogvideo: CogVideoConfig = field(default_factory=CogVideoConfig)
    sr_prior: SRPriorConfig = field(default_factory=SRPriorConfig)

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise InputError(f"restorer kind {self.kind!r} is unknown; choose one of {', '.join(KINDS)}")

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any] | None) -> "RestoreConfig":
        """From ``to_dict()`` output. Keys of ``ReferenceWarpConfig`` at the top level (the older flat
        ``restorer`` section, e.g. ``restorer.use_extra_views``) go to ``warp``; unknown keys raise."""
        d = dict(d or {})
        sections = {"warp": ReferenceWarpConfig, "learned": LearnedRestorerConfig, "cogvideo": CogVideoConfig,
                    "sr_prior": SRPriorConfig}
        parts: dict[str, dict[str, Any]] = {name: dict(d.pop(name, None) or {}) for name in sections}
        kind = d.pop("kind", "warp")
        warp_fields = {f.name for f in dataclasses.fields(ReferenceWarpConfig)}
        for key in list(d):
            if key in warp_fields:
                parts["warp"][key] = d.pop(key)
        if d:
            raise InputError(f"restorer config: unknown key(s) {sorted(d)}; expected kind, warp, learned, cogvideo, "
                             "sr_prior (or ReferenceWarpConfig fields)")
        built = {}
        for name, klass in sections.items():
            known = {f.name for f in dataclasses.fields(klass)}
            unknown = set(parts[name]) - known
            if unknown:
                raise InputError(f"restorer config: unknown {name} setting(s) {sorted(unknown)}; known: {sorted(known)}")
            try:
                built[name] = klass(**parts[name])
            except (TypeError, ValueError) as exc:  # a value of the wrong type meets a range check
                raise InputError(f"restorer config: {name} setting(s) {parts[name]}: {exc}") from None
        return cls(kind=str(kind), **built)

    def settings_key(self) -> dict[str, Any]:
        """JSON-able: exactly the settings that change a pseudo-target of this kind (the prior's
        only when it is enabled, so keys of runs without it stay as they were)."""
        if self.kind == "warp":
            key = {"kind": "warp", "warp": dataclasses.asdict(self.warp)}
        elif self.kind == "learned":
            key = {"kind": "learned", "warp": dataclasses.asdict(self.warp), "learned": dataclasses.asdict(self.learned)}
        else:
            key = {"kind": "cogvideo", "cogvideo": dataclasses.asdict(self.cogvideo)}
        if self.sr_prior.enabled:
            key["sr_prior"] = dataclasses.asdict(self.sr_prior)
        return key
