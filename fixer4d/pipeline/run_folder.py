"""A run folder: its versioned config, its stage records, its scene (docs/design.md §6).

    RUN/config.json   {"format_version": FORMAT_VERSION, "fixer4d": version, "source_commit": the
                      code's git commit (None outside a checkout), "config": RunConfig}
    RUN/stages.json   {stage: {"key": inputs key, "seconds": s, "done": bool}}

Every entry point opens a run through ``RunFolder``: ``create`` for a new or resumed run (refuses a
folder that holds another configuration, naming the keys that differ), ``open`` for an existing one
(refine, eval, the viewer). A format-1 folder (the first landing) is migrated in place, its old
config kept as ``config.v1.json``; a format-2 one is rewritten with its renamed sections
(``pipeline.config.RENAMED_SECTIONS``); anything else that is not a fixer4d run is refused in one sentence.
"""
from __future__ import annotations

import hashlib
import json
import logging
import shutil
from pathlib import Path
from typing import Any

from fixer4d import atomic
from fixer4d.errors import InputError
from fixer4d.jsonfile import read_json_object
from fixer4d.pipeline import config_tree
from fixer4d.pipeline.capture_rig import RUN_RIG_NAME
from fixer4d.pipeline.config import FORMAT_VERSION, RunConfig, as_saved, migrate_v1

log = logging.getLogger("fixer4d.pipeline")

CONFIG_NAME = "config.json"
STAGES_NAME = "stages.json"


def stage_key(*parts: Any) -> str:
    """A short stable hash of everything a stage's output depends on."""
    return hashlib.sha1(json.dumps(parts, sort_keys=True, default=str).encode()).hexdigest()[:16]


def _version() -> str:
    from fixer4d import __version__

    return __version__


def source_commit() -> str | None:
    """The git commit of the fixer4d code running now ("abc1234", "+changes" when tracked files
    differ from it), so a result can name the code that produced it; None outside a git checkout."""
    import subprocess

    root = Path(__file__).resolve().parents[2]
    try:
        head = subprocess.run(["git", "-C", str(root), "rev-parse", "--short", "HEAD"], capture_output=True,
                              text=True, timeout=10)
        if head.returncode != 0:
            return None
        dirty = subprocess.run(["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True, timeout=10).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return None
    return head.stdout.strip() + ("+changes" if dirty else "")


class StageRecords:
    """RUN/stages.json: per stage the key of its inputs, its seconds and whether it finished.

    A stage is reused only when it finished with the same key; a stage started under another key
    is invalidated (its outputs are the caller's to clear, see ``begin``).
    """

    def __init__(self, path: Path) -> None:
        self.path = path
        self.records: dict[str, dict[str, Any]] = {}
        if path.exists():
            try:
                raw = json.loads(path.read_text())
            except json.JSONDecodeError as exc:
                raise InputError(f"{path}: not valid JSON ({exc}); delete it to recompute every stage") from None
            for name, rec in raw.items():  # format 1 stored bare seconds, trusted once
                self.records[name] = rec if isinstance(rec, dict) else {"key": None, "seconds": float(rec), "done": True}

    def done(self, name: str, key: str) -> bool:
        rec = self.records.get(name)
        if rec is None or not rec.get("done"):
            return False
        if rec.get("key") is None:  # migrated from format 1: adopt the current key
            rec["key"] = key
            self._save()
        return rec["key"] == key

    def begin(self, name: str, key: str) -> bool:
        """Mark ``name`` as running under ``key``; True when an earlier attempt ran under another
        key (its partial outputs must not be resumed)."""
        rec = self.records.get(name)
        stale = rec is not None and rec.get("key") not in (None, key)
        self.records[name] = {"key": key, "seconds": 0.0, "done": False}
        self._save()
        return stale

    def forget(self, name: str) -> bool:
        """Drop stage ``name``'s record (a stage the config no longer runs); True when there was one."""
        if self.records.pop(name, None) is None:
            return False
        self._save()
        return True

    def finish(self, name: str, key: str, seconds: float) -> None:
        self.records[name] = {"key": key, "seconds": float(seconds), "done": True}
        self._save()

    def seconds(self, *names: str) -> float:
        return float(sum(self.records.get(n, {}).get("seconds", 0.0) for n in names))

    def as_seconds(self) -> dict[str, float]:
        return {n: float(r.get("seconds", 0.0)) for n, r in self.records.items() if r.get("done")}

    def _save(self) -> None:
        atomic.write_json(self.path, self.records)


class RunFolder:
    """One run: ``path``, its resolved ``config`` and its ``records``."""

    def __init__(self, path: Path, config: RunConfig) -> None:
        self.path = path
        self.config = config
        self.records = StageRecords(path / STAGES_NAME)
        self._scene = None

    # -- opening ------------------------------------------------------------------------------
    @classmethod
    def create(cls, path: str | Path, config: RunConfig) -> "RunFolder":
        """A new run, or the resumption of one with the same configuration.

        Raises InputError (nothing written) when ``path`` is a file, a foreign folder or a run
        with another configuration.
        """
        path = Path(path)
        if path.exists() and not path.is_dir():
            raise InputError(f"--out {path}: is a file, not a run folder")
        if (path / CONFIG_NAME).exists():
            previous = cls.open(path).config
            changes = config_tree.diff(previous.to_dict(), config.to_dict())
            from fixer4d.train.checkpoints import RESULT_NEUTRAL

            # how the run is carried out (display, checkpoint cadence, workers), not what it computes,
            # may change on a resume
            neutral = {f"training.{k}" for k in RESULT_NEUTRAL}
            changes = [c for c in changes if c.split(":")[0] not in neutral]
            if changes:
                from fixer4d.train.config import SCHEDULE_KEYS

                # the keys a user sets first, the densification schedule an iteration count implies last
                derived = tuple(f"training.{k}" for k in SCHEDULE_KEYS)
                changes = sorted(changes, key=lambda c: c.startswith(derived))
                shown = "; ".join(changes[:4]) + (f"; and {len(changes) - 4} more" if len(changes) > 4 else "")
                raise InputError(f"{path} holds a run with a different configuration ({shown}); use another --out, "
                                 f"`fixer4d refine {path}` to change stage-2 settings, or delete the folder")
        # a capture's rig.json is calibrated into the folder before the run starts
        elif path.is_dir() and any(p for p in path.iterdir() if not p.name.startswith(".") and p.name != RUN_RIG_NAME):
            raise InputError(f"--out {path}: exists and is not a fixer4d run folder (no {CONFIG_NAME}); "
                             "choose an empty or new folder")
        path.mkdir(parents=True, exist_ok=True)
        for leftover in atomic.clean_temporaries(path):  # half-written files of a killed run
            log.info("removed the temporary %s left by an interrupted write", leftover)
        folder = cls(path, config)
        folder.save_config()
        return folder

    @classmethod
    def open(cls, path: str | Path) -> "RunFolder":
        """An existing run (migrating an older format's config.json in place)."""
        path = Path(path)
        config, version = _read_config(path)
        folder = cls(path, config)
        if version is None:
            shutil.copy2(path / CONFIG_NAME, path / "config.v1.json")
        if version != FORMAT_VERSION:
            folder.save_config()
        return folder

    def save_config(self) -> None:
        atomic.write_json(self.path / CONFIG_NAME, {"format_version": FORMAT_VERSION, "fixer4d": _version(),
                                                    "source_commit": source_commit(),
                                                    "config": self.config.to_dict()})

    def update_config(self, config: RunConfig) -> None:
        self.config = config
        self.save_config()

    # -- the scene ------------------------------------------------------------------------------
    @property
    def scene(self):
        """The run's scene (loaded once)."""
        if self._scene is None:
            self._scene = load_scene_for(self.config)
        return self._scene


def read_run_config(path: str | Path) -> RunConfig:
    """The typed config of an existing run folder, read only (a format-1 folder is migrated in
    memory, not on disk): what viewers and tools that must not write into a run call."""
    return _read_config(Path(path))[0]


def _read_config(path: Path) -> tuple[RunConfig, int | None]:
    """(config, format version or None for format 1) of the run folder ``path``; InputError in one
    sentence for a missing, foreign, damaged or newer folder."""
    cfg_path = path / CONFIG_NAME
    if not path.is_dir():
        raise InputError(f"{path}: no such run folder")
    if not cfg_path.is_file():
        raise InputError(f"{path}: not a fixer4d run folder (no {CONFIG_NAME}); make one with `fixer4d run`")
    data = read_json_object(cfg_path, str(cfg_path), "the run folder is damaged; start a new run")
    version = data.get("format_version")
    if version is None:
        if "scene" not in data:
            raise InputError(f"{cfg_path}: not a fixer4d run config (no format_version, no scene)")
        return RunConfig.from_dict(as_saved(migrate_v1(data))), None
    if not isinstance(version, int) or version > FORMAT_VERSION:
        raise InputError(f"{path}: run folder format {version!r} is newer than this fixer4d understands "
                         f"({FORMAT_VERSION}); update fixer4d")
    return RunConfig.from_dict(as_saved(data.get("config") or {}), str(cfg_path)), version


def load_scene_for(config: RunConfig):
    """The scene a config names, with its scale and frame range."""
    from fixer4d.scene import load_scene

    sc = config.scene
    return load_scene(sc.source, scale=sc.scale, frame_range=None if sc.frame_range is None else tuple(sc.frame_range),
                      calibration=sc.calibration, offsets=sc.offsets, holdout=sc.holdout)
