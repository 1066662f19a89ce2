"""Training checkpoints on disk: RUN/checkpoints/stage{S}_{STEP:07d}.pt, written atomically, the
newest ``keep`` kept, read back without unpickling code.

The state inside is ``Trainer.state_dict()``; this module owns its format number, the check that
a checkpoint belongs to the trainer resuming from it, and the files.
"""
from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import torch

from fixer4d.atomic import atomic_path
from fixer4d.errors import InputError
from fixer4d.train.config import Stage2Config, TrainingConfig
from fixer4d.train.device import device_kind

# Version of the checkpoint layout (the keys of Trainer.state_dict()), bumped when they change meaning.
# Checkpoints hold tensors, numbers, strings and containers only, so that they load with
# torch.load(weights_only=True).
CHECKPOINT_FORMAT = 1
CHECKPOINT_DIR = "checkpoints"
_CKPT_NAME = re.compile(r"^stage(\d)_(\d{7})\.pt$")
# The temporary that fixer4d.atomic.atomic_path writes a checkpoint to before the rename.
_CKPT_TEMP = re.compile(r"^\.stage(\d)_\d{7}\.pt\..+$")
# Training settings that do not change a result (progress display, checkpoint cadence): a run
# may resume with other values.
RESULT_NEUTRAL = ("progress", "checkpoint_every", "keep_checkpoints", "field_workers")


def result_settings(config: dict[str, Any]) -> dict[str, Any]:
    """A TrainingConfig's settings that decide its result: all but the result-neutral ones, the
    opacity decay's when it is off, the init subsample when it is the random draw, the field count
    when it is one, the depth prior and the axis-ratio term when they are off, and the requested
    ``device``, which decides
    nothing until resolved: the device a training runs on (``device_kind``) is recorded beside
    them instead."""
    out = {k: v for k, v in config.items() if k not in RESULT_NEUTRAL and k != "device"}
    # the reset (an opacity decay that is off), the random init subsample, one field, no depth
    # prior and no axis-ratio term key a training as every training from before those settings
    # existed, so its finished stages stay valid
    if not (out.get("opacity_decay") or {}).get("enabled", False):
        out.pop("opacity_decay", None)
    if out.get("init_subsample") == "random":
        out.pop("init_subsample")
    if out.get("fields") == 1:
        out.pop("fields")
    prior = out.get("depth_prior") or {}
    if not (prior.get("weight", 0.0) > 0.0 or prior.get("novel_weight", 0.0) > 0.0):
        out.pop("depth_prior", None)
    if not out.get("scale_ratio_weight", 0.0) > 0.0:
        for key in ("scale_ratio_weight", "scale_ratio_max", "scale_ratio_against"):
            out.pop(key, None)
    return out


def training_settings(config: TrainingConfig, stage2: Stage2Config | None) -> dict[str, Any]:
    """The settings a checkpoint records and a resume must match: "config" (``result_settings``),
    "stage2" (the Stage2Config, None in stage 1) and "device", where the training runs ("cpu" |
    "cuda")."""
    return {"config": result_settings(config.to_dict()), "stage2": None if stage2 is None else stage2.keyed(),
            "device": device_kind(config.device, config.backend)}


def check_resumable(state: dict[str, Any], stage: int, settings: dict[str, Any], source: str) -> None:
    """Raise InputError unless ``state`` has this format, is of ``stage`` and was written with
    ``settings`` (``training_settings``); ``source`` names it in the message."""
    fmt = state.get("format")
    if fmt != CHECKPOINT_FORMAT:
        raise InputError(f"{source}: checkpoint format {fmt!r}, but this fixer4d reads format "
                         f"{CHECKPOINT_FORMAT}; delete RUN/checkpoints to retrain this stage, or use the "
                         "fixer4d version that wrote it")
    if state.get("stage") != stage:
        raise InputError(f"{source}: a stage-{state.get('stage')} checkpoint where stage {stage} was "
                         "expected; delete it or train into a new run folder")
    if (state["config"], state["stage2"]) != (settings["config"], settings["stage2"]):
        raise InputError(f"{source}: written with another training config; resume with the same options, "
                         "or delete RUN/checkpoints to start over")
    # a checkpoint from before the device was recorded resumes anywhere, as it always did
    trained_on = state.get("device", settings["device"])
    if trained_on != settings["device"]:
        raise InputError(f"{source}: trained on {trained_on}, but this training runs on {settings['device']}: one "
                         f"training's result comes from one device; resume it where it ran (training.device="
                         f"{trained_on}), or delete RUN/checkpoints to train it again here")


def write_checkpoint(state: dict[str, Any], run_dir: str | Path, stage: int, step: int, keep: int) -> Path:
    """Write ``state`` to RUN/checkpoints/stage{stage}_{step}.pt atomically, then delete all but
    the newest ``keep`` (at least 1) checkpoints of the stage."""
    path = Path(run_dir) / CHECKPOINT_DIR / f"stage{stage}_{step:07d}.pt"
    with atomic_path(path) as tmp:
        torch.save(state, tmp)
    for old in list_checkpoints(run_dir, stage)[:-max(keep, 1)]:
        old.unlink(missing_ok=True)
    return path


def list_checkpoints(run_dir: str | Path, stage: int) -> list[Path]:
    """Complete checkpoints of ``stage`` in RUN/checkpoints, oldest first."""
    d = Path(run_dir) / CHECKPOINT_DIR
    if not d.is_dir():
        return []
    found = [(int(m.group(2)), p) for p in d.iterdir()
             if (m := _CKPT_NAME.match(p.name)) and int(m.group(1)) == stage]
    return [p for _, p in sorted(found)]


def remove_partial_checkpoints(run_dir: str | Path, stage: int) -> int:
    """Delete the checkpoint temporaries of ``stage`` (``.stage{S}_{STEP}.pt.*``) that a process
    killed inside ``write_checkpoint`` left; the complete checkpoints are never touched. Returns
    how many were deleted."""
    d = Path(run_dir) / CHECKPOINT_DIR
    if not d.is_dir():
        return 0
    partial = [p for p in d.iterdir() if (m := _CKPT_TEMP.match(p.name)) and int(m.group(1)) == stage]
    for p in partial:
        p.unlink(missing_ok=True)
    return len(partial)


def read_checkpoint(path: str | Path) -> dict[str, Any]:
    """The state dict stored in checkpoint ``path``, read without unpickling code.

    ``torch.load(weights_only=True)`` rebuilds tensors, numbers, strings and containers only; a
    file whose pickle names any other global (a ``__reduce__`` payload, a pickled class) is
    refused with an InputError before anything in it runs. Truncated or foreign files get an
    InputError naming the file and the fix.
    """
    import pickle

    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such checkpoint; list RUN/checkpoints or start the stage over")
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as exc:
        # torch wraps the unpickler's complaint in a long advisory; keep its "WeightsUnpickler error"
        detail = str(exc).partition("WeightsUnpickler error:")[2].partition("Check the documentation")[0]
        detail = " ".join(detail.split()) or type(exc).__name__
        if "Unsupported global" in detail:  # a global other than tensors/containers: code or an object
            name = detail.partition("GLOBAL ")[2].partition(" ")[0] or "?"
            raise InputError(f"{path}: refused to load: the checkpoint contains pickled code or objects ({name}), "
                             "not only tensors; fixer4d never executes a checkpoint; delete it (fixer4d did not "
                             "write it) to resume from an older one") from None
        raise InputError(f"{path}: unreadable checkpoint ({detail[:200]}); delete it to resume from an older "
                         "one") from None
    except Exception as exc:  # a truncated or foreign file: say which and what to do
        raise InputError(f"{path}: unreadable checkpoint ({type(exc).__name__}: {str(exc)[:200]}); delete it to "
                         "resume from an older one") from None
    if not isinstance(state, dict):
        raise InputError(f"{path}: not a fixer4d checkpoint (holds a {type(state).__name__}, not a state dict); "
                         "delete it to resume from an older one")
    return state
