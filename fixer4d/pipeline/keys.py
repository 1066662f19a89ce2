"""The keys of the stages: a short hash of everything a stage's output depends on.

A finished stage is reused only under the same key; the stage-2 key is also the restoration
cache's fingerprint, so a pseudo-target made under other settings is never served.
"""
from __future__ import annotations

from typing import Any

from fixer4d.pipeline.config import RunConfig
from fixer4d.pipeline.run_folder import stage_key
from fixer4d.pipeline.self_check import fold_fields
from fixer4d.train.checkpoints import result_settings
from fixer4d.train.device import device_kind

__all__ = ["init_key", "stage1_key", "field_key", "restorer_key", "stage2_key", "matched_key", "self_check_key",
           "SELF_CHECK_DECISION_SETTINGS", "training_settings", "trajectory_settings",
           "shared_static_key", "co_fields_key", "co_fields_weight_key"]


# ---------------------------------------------------------------------------------------------
def training_settings(training: dict[str, Any]) -> dict[str, Any]:
    """The training settings that change the trained model (``checkpoints.result_settings``) and,
    for a training on CUDA, the device: CUDA and the CPU give other digits, so a stage trained on
    one is not reused for a run on the other. The CPU adds nothing, so the keys of CPU trainings
    (every run folder from before the device was keyed) stay as they were."""
    out = result_settings(training)
    kind = device_kind(training["device"], training["backend"])
    if kind != "cpu":
        out["trained_on"] = kind
    return out


def scene_settings(scene: dict[str, Any]) -> dict[str, Any]:
    """The scene section as it enters the keys: capture-only settings (calibration, offsets,
    holdout) only where set, so adding such a setting to fixer4d leaves every earlier run's
    keys, and its finished stages, as they were."""
    return {k: v for k, v in scene.items() if not (k in CAPTURE_SETTINGS and v is None)}


# SceneConfig fields that only a capture folder uses (None elsewhere)
CAPTURE_SETTINGS = ("calibration", "offsets", "holdout")


def init_key(config: RunConfig, method: str) -> str:
    d = config.to_dict()
    return stage_key("init", method, scene_settings(d["scene"]), {**d["init"], "method": method},
                     config.init_frame_stride)


def stage1_key(config: RunConfig, method: str) -> str:
    d = config.to_dict()
    training = training_settings(d["training"])
    if method != config.init_method:  # the sparse baseline trains one field without the depth prior
        training.pop("depth_prior", None)
        training.pop("fields", None)
    # the sections' contents are hashed, not their names: "model_terms" (formerly "effects") keys as before
    return stage_key("stage1", init_key(config, method), training, config.seed,
                     d["model_terms"], *shared_static_key(config),
                     *(co_fields_key(config) if method == config.init_method else ()))


def field_key(config: RunConfig, field: int) -> str:
    """The key of field ``field`` of the main init's stage 1 (``training.fields`` > 1): stage 1's
    key under one field count, since a field's training (its seed, init draw and budget) does not
    depend on how many fields are merged."""
    import dataclasses

    one = dataclasses.replace(config, training=dataclasses.replace(config.training, fields=1))
    return stage_key("stage1 field", stage1_key(one, config.init_method), int(field))


def co_fields_key(config: RunConfig) -> tuple[Any, ...]:
    """() with co_fields off, so that every run without a twin field keeps its keys; while on,
    the settings the main init's stage 1 trains its twin and co-prunes with (the sparse
    baseline's stage 1 trains alone either way)."""
    cf = config.co_fields
    return ("co_fields", cf.stage1_settings()) if cf.enabled else ()


def co_fields_weight_key(config: RunConfig) -> tuple[Any, ...]:
    """() unless co_fields is on; then which per-pixel weight gates the restorations."""
    cf = config.co_fields
    return ("co_fields_weight", cf.weight) if cf.enabled else ()


def shared_static_key(config: RunConfig) -> tuple[str, ...]:
    """() for a run of its own; for a later segment, the content of the shared static rows it
    trains on top of (a changed first segment retrains it)."""
    if config.segments.static_from is None:
        return ()
    from fixer4d.pipeline.shared_static import digest

    return ("shared_static", digest(config.segments.static_from))


def stage2_key(config: RunConfig) -> str:
    """Stage 2 and its pseudo-targets: the stage-1 model, stage-2 settings, restorer, trajectories
    (and the unobserved fill's depth tolerance when the targets fall back on the fill)."""
    from fixer4d.restore.unobserved_fill import BACKGROUND_DEPTH_TOL

    d = config.to_dict()
    fill = ("fill_background_tol", BACKGROUND_DEPTH_TOL) if config.stage2.fill_unobserved else ()
    return stage_key("stage2", stage1_key(config, config.init_method), config.stage2.keyed(), restorer_key(config),
                     *co_fields_weight_key(config),
                     trajectory_settings(d["trajectories"]), *fill)


def trajectory_settings(trajectories: dict[str, Any]) -> dict[str, Any]:
    """The trajectories section as it enters the keys: the undetermined views' settings only while
    they are on, so that a run with them off keeps the keys (and finished stages) it had before
    they existed."""
    if trajectories.get("undetermined_views", 0):
        return trajectories
    return {k: v for k, v in trajectories.items() if not k.startswith(UNDETERMINED_PREFIX)}


# TrajectoryConfig fields of the undetermined views (pipeline.undetermined_views)
UNDETERMINED_PREFIX = "undetermined_"


def restorer_key(config: RunConfig) -> str:
    """The restorer's outputs: its settings, and for the learned one what it was trained from."""
    rc = config.restorer
    if rc.kind != "learned":
        return stage_key("restorer", rc.settings_key())
    return stage_key("restorer", rc.settings_key(), init_key(config, config.init_method),
                     training_settings(config.to_dict()["training"]), config.seed, *shared_static_key(config))


def matched_key(config: RunConfig) -> str:
    """The matched-iterations control: the stage-1 model and the training it continues with
    (``matched_config``), so stage-2 settings it never reads (the pseudo-targets') leave it as it is."""
    from fixer4d.train.config import matched_config
    from fixer4d.train.fields import refined_apart

    continued = matched_config(config.training, config.stage2).to_dict()
    apart = ("fields_apart",) if refined_apart(config.training, config.stage2) else ()
    return stage_key("matched", stage1_key(config, config.init_method), training_settings(continued), *apart)


# The self-check's settings that only decide from the fold's figures: changing them re-decides
# from the finished fold instead of training it again.
SELF_CHECK_DECISION_SETTINGS = ("tie_db", "allow_skip", "allow_continue", "margin")


def self_check_key(config: RunConfig) -> str:
    """The stage-2 self-check's fold: everything stage 2 depends on, and the check's own settings
    but those of the decision (``SELF_CHECK_DECISION_SETTINGS``)."""
    fold = {k: v for k, v in config.to_dict()["self_check"].items() if k not in SELF_CHECK_DECISION_SETTINGS}
    # settings at the values every check had before they existed leave those checks' keys as they were
    for name, before in (("cameras", 1), ("scale_budget", False)):
        if fold.get(name) == before:
            fold.pop(name)
    fold.pop("fields", None)  # keyed as the count the fold trains (fold_fields, below)
    # a learned restorer is trained again inside the fold, on the fold's cameras only
    own_restorer = ("fold_restorer",) if config.restorer.kind == "learned" else ()
    # the fold's stage 1: the run's fields merged (train.fields), or one field (pipeline.self_check.fold_fields)
    n = fold_fields(config)
    fields = ("fold_fields", n) if n > 1 else ()
    return stage_key("self_check", stage2_key(config), fold, config.init_frame_stride, *own_restorer, *fields)
