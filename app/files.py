"""Files the viewer reads and writes: model versions of a run folder, model files, and where
the viewer's own outputs go (never the working directory).

A run folder (``fixer4d run`` / ``reconstruct`` output, with config.json) holds model versions:
``model_final.ply``, ``model_stage1.ply`` and the viewer's edits ``model_edit_<k>.ply``; a run
trained with ``co_fields`` also keeps the second stage-1 field, ``model_stage1_twin.ply``, and a
run of several fields (``training.fields``) keeps each field before the merge, ``fields/field<k>/``. The
session remembers the version last shown (``AppState.model_version``), so a saved edit is what
the run reopens with. A bare model file (.ply or .npz) opens without a scene; when it sits in a
run folder, that run's scene and cache come with it.
"""
from __future__ import annotations

import json
import re
from pathlib import Path

from fixer4d.errors import InputError

MODEL_SUFFIXES = (".ply", ".npz")
# Model versions a run opens with when the session names none, in order of preference.
DEFAULT_VERSIONS = ("model_final.ply", "model_stage1.ply")
EDIT_PATTERN = re.compile(r"^model_edit_(\d+)\.ply$")
# A run trained with co_fields keeps the second of its two stage-1 fields under this name
# (fixer4d.train.co_fields.TWIN_NAME); a model file outside a run has its twin as <stem>_twin<suffix>.
RUN_TWIN = "model_stage1_twin.ply"
TWIN_SUFFIX = "_twin"
# A run of several stage-1 fields keeps its first two fields here (fixer4d.train.fields.field_dir):
# two seeds' guesses, compared with each other where the run has no co_fields twin.
RUN_FIRST_FIELD = Path("fields") / "field0" / "model.ply"
RUN_SECOND_FIELD = Path("fields") / "field1" / "model.ply"


def is_run_folder(path: Path) -> bool:
    return Path(path).is_dir() and (Path(path) / "config.json").is_file()


def is_model_file(path: Path) -> bool:
    return Path(path).suffix.lower() in MODEL_SUFFIXES


def model_versions(run: Path) -> list[Path]:
    """The run's model files: the pipeline's (final, stage 1), the viewer's edits in order, then
    any other model file at the top of the folder."""
    run = Path(run)
    if not run.is_dir():
        return []
    edits = sorted((p for p in run.glob("model_edit_*.ply") if EDIT_PATTERN.match(p.name)),
                   key=lambda p: int(EDIT_PATTERN.match(p.name).group(1)))
    named = [run / n for n in DEFAULT_VERSIONS if (run / n).is_file()]
    others = sorted(p for p in run.iterdir() if p.is_file() and is_model_file(p) and p not in named and p not in edits)
    return named + edits + others


def twin_pair(model: Path | None) -> tuple[Path | None, Path] | None:
    """What the undetermined map compares for the model file ``model``: (first, twin), where
    first None is the shown model itself; None when there is no twin. In a run folder: the shown
    model and the run's ``model_stage1_twin.ply`` (co_fields; the pipeline compares every later
    model of the run with it too: stage 2, edits), else the run's two stage-1 fields with each
    other (``fields/field0``, ``fields/field1``: every model of the run shows their
    disagreement); elsewhere the model and ``<stem>_twin<suffix>`` beside the file. A model is
    never its own twin."""
    if model is None:
        return None
    model = Path(model)
    if is_run_folder(model.parent):
        run = model.parent
        if (run / RUN_TWIN).is_file() and run / RUN_TWIN != model:
            return None, run / RUN_TWIN
        first, second = run / RUN_FIRST_FIELD, run / RUN_SECOND_FIELD
        return (first, second) if first.is_file() and second.is_file() else None
    twin = model.with_name(model.stem + TWIN_SUFFIX + model.suffix)
    return (None, twin) if twin.is_file() and twin != model else None


def next_edit_path(folder: Path) -> Path:
    """``folder/model_edit_<k>.ply`` with k one past the highest existing edit."""
    ks = [int(m.group(1)) for p in Path(folder).glob("model_edit_*.ply") if (m := EDIT_PATTERN.match(p.name))]
    return Path(folder) / f"model_edit_{max(ks, default=0) + 1}.ply"


def remembered_version(session_path: Path | None) -> str | None:
    """The model version named in a saved session (None when absent or unreadable)."""
    if session_path is None or not Path(session_path).is_file():
        return None
    try:
        name = json.loads(Path(session_path).read_text()).get("model_version")
    except (ValueError, AttributeError, OSError):
        return None
    return str(name) if isinstance(name, str) and name else None


def choose_model(run: Path, remembered: str | None = None) -> Path:
    """The version a run opens with: the remembered one if it still exists, else model_final,
    else model_stage1, else the newest edit."""
    run = Path(run)
    if remembered and (run / remembered).is_file() and is_model_file(run / remembered):
        return run / remembered
    versions = model_versions(run)
    if not versions:
        raise InputError(f"{run}: no model in this run folder yet (model_final.ply / model_stage1.ply); "
                         "run `fixer4d reconstruct` first")
    return versions[0]


def resolve_output(text: str, base: Path) -> Path:
    """A user-typed path as an absolute one: ``~`` expanded, relative paths under ``base`` (the
    run folder or the viewer's session folder), never the process's working directory."""
    p = Path(str(text).strip()).expanduser()
    if not str(text).strip():
        raise InputError("no file name given")
    return p if p.is_absolute() else (Path(base) / p).resolve()


def resolve_input(text: str, base: Path) -> Path:
    """A user-typed path to read: as typed when it is absolute, else under ``base``; a missing
    file is an InputError naming the full path."""
    p = resolve_output(text, base)
    if not p.exists():
        raise InputError(f"{p}: no such file or folder")
    return p


# Entries kept in the recently-opened list (the start chooser shows them).
MAX_RECENT = 12
RECENT_FILE = "recent.json"


def recent(config_dir: Path) -> list[str]:
    """Recently opened sources (newest first) from ``config_dir/recent.json``; [] when absent
    or unreadable."""
    try:
        items = json.loads((Path(config_dir) / RECENT_FILE).read_text())
    except (ValueError, OSError):
        return []
    return [str(x) for x in items if isinstance(x, str)][:MAX_RECENT] if isinstance(items, list) else []


def remember_recent(config_dir: Path, source: str) -> None:
    """Put ``source`` first in the recently-opened list."""
    from fixer4d.atomic import write_json

    items = [source] + [x for x in recent(config_dir) if x != source]
    Path(config_dir).mkdir(parents=True, exist_ok=True)
    write_json(Path(config_dir) / RECENT_FILE, items[:MAX_RECENT])
