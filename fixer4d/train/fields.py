"""Stage 1 as several fields, merged into one model (``training.fields``).

Stage 1 is chaotic in its seed: two seeds' models (the init's subsample draw and the training's
draws) read up to 1 dB apart on held-out cameras, and the per-pixel mean of their renders beats
both (docs/decisions/seed-ensemble.md, two-fields.md). A mean of renders is not a model the viewer, the exports
or stage 2 can use; the union of the fields' Gaussians with every opacity divided by the field
count is. Where the fields agree on a surface the union composites the same colour at about the
same coverage as either field; where only one field has a Gaussian (a floater, a guess about a
region no camera determines) it shows at 1/n of its opacity, as in the mean of the renders.

    train_fields(make_trainer, n, dir) -> field k trains with seed + k x FIELD_SEED_OFFSET under
                                 dir/fields/field<k>/ (its model and record, training seconds,
                                 revisions and camera response, written there when done; a resumed stage 1 reads
                                 the finished fields back and resumes the ones in progress), side by
                                 side in worker processes where the caller gives a recipe
                                 (train.field_workers), then the fields are merged:
    merge_fields(models)      -> the union, opacities / n                (N_1 + ... + N_n rows)
    mean_response(responses)  -> the camera response of the merged model (the fields' mean)

The pipeline's stage 1 (RUN/fields/) and the self-check's fold (its stage1/fields/) train the
same way, so that the fold checks stage 2 on the kind of model the run refines.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Callable, Sequence

import torch

from fixer4d.errors import InputError
from fixer4d.model.camera_response import CameraResponse
from fixer4d.model.spacetime import SpacetimeGaussians

if TYPE_CHECKING:
    from fixer4d.train.config import Stage2Config, TrainingConfig
    from fixer4d.train.field_workers import FieldRecipe
    from fixer4d.train.trainer import Trainer

# Field k's seed is the run's plus k times this: far from the seeds a study sweeps (0, 1, 2, ...),
# so that a field of one run never repeats another run's first field.
FIELD_SEED_OFFSET = 1_000_003
# The fields' folder in the run folder, a field's finished model there, and its record (training
# seconds over every attempt, term revisions, camera response).
FIELDS_DIR = "fields"
FIELD_MODEL = "model.ply"
FIELD_RECORD = "field.json"
# The key of the settings a field trains under, written when its training starts: a stage 1 made
# again under another field count keeps the fields whose key it shares (``keep_matching_fields``).
FIELD_KEY = "key.txt"


def field_seed(seed: int, field: int) -> int:
    """The training seed of field ``field`` (0-based) of a run with ``seed``; field 0 keeps it."""
    return int(seed) + int(field) * FIELD_SEED_OFFSET


def merged_training(training: "TrainingConfig") -> "TrainingConfig":
    """``training`` for the trainings that continue a merged model (stage 2, the matched control,
    the self-check's candidates): the Gaussian budget of all its ``training.fields`` fields."""
    import dataclasses

    return dataclasses.replace(training, max_gaussians=training.max_gaussians * training.fields)


def refined_apart(training: "TrainingConfig", stage2: "Stage2Config") -> bool:
    """Stage 2 and the matched control continue each of several fields apart (``stage2.fields``)."""
    return stage2.fields == "apart" and training.fields > 1


def field_dir(run_dir: str | Path, field: int, step: str | None = None) -> Path:
    """RUN/fields/field<k>/: field ``field``'s stage-1 checkpoints and finished files; with
    ``step``, its subfolder of a later training that continues the field apart (e.g. "stage2")."""
    out = Path(run_dir) / FIELDS_DIR / f"field{int(field)}"
    return out if step is None else out / step


def merge_fields(models: Sequence[SpacetimeGaussians]) -> SpacetimeGaussians:
    """One model from n fields: every field's rows, each opacity sigmoid(o) replaced by
    sigmoid(o) / n (in logit space, float64 on the way, finite for every finite logit). The fields must share their model terms
    (the same init decides them); the ``dynamic`` and ``frozen`` buffers follow their rows.
    Frozen rows (a later segment's shared static Gaussians, the same in every field) are kept
    once, from field 0, at their own opacity."""
    if not models:
        raise InputError("merge_fields: no fields to merge")
    config = models[0].config
    for k, m in enumerate(models[1:], 1):
        if m.config != config:
            raise InputError(f"merge_fields: field {k} has the model terms {m.config.to_dict()}, field 0 "
                             f"{config.to_dict()}; the fields of one stage 1 share their init's terms")
        if m.num_frozen != models[0].num_frozen:
            raise InputError(f"merge_fields: field {k} has {m.num_frozen} frozen rows, field 0 "
                             f"{models[0].num_frozen}; the fields of one stage 1 share their frozen rows")
    n = len(models)
    if n == 1:
        return SpacetimeGaussians.from_tensors(config, models[0].tensors(), source="merge_fields")
    rows = [m.tensors() for m in models]
    keep = [torch.ones(m.num_gaussians, dtype=torch.bool) if k == 0 else ~m.frozen.cpu()
            for k, m in enumerate(models)]
    tensors = {name: torch.cat([r[name].detach().cpu()[kept] for r, kept in zip(rows, keep)])
               for name in rows[0]}
    logits = tensors["opacity_logits"]
    # log(sigmoid(o) / n) through softplus: finite for any finite logit (a plain sigmoid underflows
    # to 0 below o = -745, whose log is -inf); then logit(p) = log p - log(1 - p)
    log_alpha = -math.log(n) - torch.nn.functional.softplus(-logits.double())
    merged = (log_alpha - torch.log1p(-torch.exp(log_alpha))).to(logits.dtype)
    tensors["opacity_logits"] = torch.where(tensors["frozen"], logits, merged)
    return SpacetimeGaussians.from_tensors(config, tensors, source="merge_fields")


def mean_response(responses: Sequence[CameraResponse | None]) -> CameraResponse | None:
    """The merged model's camera response: the mean of the fields' log gains and biases (both
    centred over the rig, so the mean is too); None when the fields have none."""
    present = [r for r in responses if r is not None]
    if not present:
        return None
    if len(present) != len(responses):
        raise InputError("mean_response: some fields have a camera response and some do not")
    out = CameraResponse(present[0].log_gain.shape[0])
    with torch.no_grad():
        out.log_gain.copy_(torch.stack([r.log_gain.detach().cpu() for r in present]).mean(0))
        out.bias.copy_(torch.stack([r.bias.detach().cpu() for r in present]).mean(0))
    return out


@dataclass
class TrainedFields:
    """``train_fields``' result: the merged model and camera response, the term revisions summed
    over the fields, and the training seconds of earlier attempts (fields read
    back, resumed fields' checkpoints) that the call's own wall time does not hold."""

    model: SpacetimeGaussians
    response: CameraResponse | None
    revisions: dict[str, int]
    prior_seconds: float


def train_fields(make_trainer: Callable[[int, Path], "Trainer"], fields: int, run_dir: str | Path,
                 finished: Callable[[Path], None] | None = None, label: str = "stage 1",
                 step: str | None = None, key: Callable[[int], str] | None = None,
                 recipe: "FieldRecipe | None" = None, workers: int = 1, progress: bool = True) -> TrainedFields:
    """Train ``fields`` fields and merge them (``merge_fields``).

    make_trainer(k, directory): field k's untrained Trainer (seed ``field_seed(seed, k)``, its
    model drawn from the init with that seed, or for a later ``step`` the field's stage-1 model,
    ``load_field``), checkpointing under ``directory`` (``field_dir(run_dir, k, step)``). A field whose
    model is already in its folder is read back, the one in progress resumes from its checkpoints;
    each finished field writes its model and record there, then ``finished(directory)`` runs (e.g.
    to drop the field's checkpoints). label: what the progress bars call the training
    ("<label>, field k/n"). key(k): field k's key, written into its folder before it trains
    (``FIELD_KEY``). recipe, workers: with a recipe (``train.field_workers``) and workers > 1, the
    unfinished fields train side by side in that many worker processes, the recipe standing in for
    make_trainer there (the same fields, byte for byte); otherwise one after the other here.
    progress: the workers' progress bar (in this process a trainer's config decides)."""
    from fixer4d.model.io import load_ply

    pending = [k for k in range(fields) if not _is_finished(field_dir(run_dir, k, step))]
    if key is not None:
        from fixer4d.atomic import write_text

        for k in pending:
            out = field_dir(run_dir, k, step)
            out.mkdir(parents=True, exist_ok=True)
            write_text(out / FIELD_KEY, key(k))
    prior, trained = 0.0, {}
    if recipe is not None and min(workers, len(pending)) > 1:
        from fixer4d.train.field_workers import train_in_workers

        jobs = [(k, field_dir(run_dir, k, step)) for k in pending]
        prior += sum(train_in_workers(recipe, jobs, workers, label, save_field, progress).values())
        if finished is not None:
            for _, out in jobs:
                finished(out)
    else:
        for k in pending:
            out = field_dir(run_dir, k, step)
            trainer = make_trainer(k, out)
            trainer.label = f"{label}, field {k + 1}/{fields}"
            prior += trainer.train_seconds if trainer.resume() else 0.0
            trainer.train()
            trained[k] = (save_field(out, trainer), trainer.response, trainer.revisions)
            if finished is not None:
                finished(out)
    models, responses, revisions = [], [], {}
    for k in range(fields):
        out = field_dir(run_dir, k, step)
        if k in trained:
            model, response, counts = trained[k]
        else:
            seconds, response, counts = _load_record(out)
            model = load_ply(out / FIELD_MODEL)
            prior += 0.0 if k in pending else seconds
        models.append(model)
        responses.append(response)
        for what, count in counts.items():
            revisions[what] = revisions.get(what, 0) + count
    return TrainedFields(merge_fields(models), mean_response(responses), revisions, prior)


def save_field(directory: str | Path, trainer: "Trainer") -> SpacetimeGaussians:
    """Write a trained field's model and record into ``directory`` (the record last: a field is
    finished when both are there); returns the model (host memory)."""
    from fixer4d.model.io import save_ply

    model = trainer.host_model()
    save_ply(model, Path(directory) / FIELD_MODEL)
    _save_record(Path(directory), trainer.train_seconds, trainer.response, trainer.revisions)
    return model


def _is_finished(directory: Path) -> bool:
    return (directory / FIELD_MODEL).exists() and (directory / FIELD_RECORD).exists()


def keep_matching_fields(run_dir: str | Path, key: Callable[[int], str]) -> list[int]:
    """Before a stage 1 under new settings: delete every field folder of RUN/fields/ whose recorded
    key (``FIELD_KEY``) is not ``key(k)`` (or that has none), so that only fields trained under the
    same settings are read back or resumed. A field does not depend on how many fields the run
    merges, so a run given more fields trains only the new ones. Returns the kept field numbers."""
    import re
    import shutil

    kept = []
    root = Path(run_dir) / FIELDS_DIR
    for folder in sorted(root.glob("field*")) if root.is_dir() else []:
        match = re.fullmatch(r"field(\d+)", folder.name)
        marker = folder / FIELD_KEY
        if match and marker.is_file() and marker.read_text() == key(int(match.group(1))):
            kept.append(int(match.group(1)))
        else:
            shutil.rmtree(folder) if folder.is_dir() else folder.unlink()
    return sorted(kept)


def load_field(run_dir: str | Path, field: int, step: str | None = None) -> tuple[SpacetimeGaussians, CameraResponse | None]:
    """Field ``field``'s finished model and camera response (of stage 1, or of ``step``)."""
    from fixer4d.model.io import load_ply

    out = field_dir(run_dir, field, step)
    if not ((out / FIELD_MODEL).is_file() and (out / FIELD_RECORD).is_file()):
        raise InputError(f"{out} holds no finished field ({FIELD_MODEL} and {FIELD_RECORD}); run stage 1 again "
                         f"(fixer4d run ... resumes it)")
    return load_ply(out / FIELD_MODEL), _load_record(out)[1]


def _save_record(directory: Path, seconds: float, response: CameraResponse | None, revisions: dict[str, int]) -> None:
    """A finished field's record beside its model (written last: a field is finished when both are)."""
    from fixer4d.atomic import write_json

    write_json(Path(directory) / FIELD_RECORD, {"train_seconds": float(seconds), "revisions": dict(revisions),
                                                "camera_response": None if response is None else response.to_json()})


def _load_record(directory: Path) -> tuple[float, CameraResponse | None, dict[str, int]]:
    saved = json.loads((Path(directory) / FIELD_RECORD).read_text())
    response = saved.get("camera_response")
    return (float(saved["train_seconds"]), None if response is None else CameraResponse.from_json(response),
            dict(saved.get("revisions") or {}))


__all__ = ["FIELD_SEED_OFFSET", "FIELDS_DIR", "FIELD_MODEL", "FIELD_RECORD", "FIELD_KEY", "field_seed", "field_dir",
           "keep_matching_fields",
           "merged_training", "refined_apart", "merge_fields", "load_field", "mean_response", "train_fields", "save_field",
           "TrainedFields"]
