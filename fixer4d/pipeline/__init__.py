"""fixer4d.pipeline: the one pipeline every entry point uses.

    config.py       typed ``RunConfig`` (one dataclass per stage, nested), ``resolve`` (defaults <-
                    config file <- --set overrides, validated in full), ``FORMAT_VERSION``
    config_tree.py  building/validating dataclass trees from dicts, dotted overrides
    run_folder.py   ``RunFolder``: versioned config.json, stage records, the run's scene
    stages.py       the stage functions (init, stage 1, stage 2, matched control, evaluate), keyed
    restoration.py  renders, restore requests, the stage-2 cache refresh, restoration rows
    stage_cache.py  finished stage outputs shared between the runs of a study
    report.py       Table-2 rows, report.json / report.md
    run.py          ``run_pipeline``: every stage in order, failures isolated per row

Its verbs (run / reconstruct / refine / eval) are in ``fixer4d.cli``.

Names are loaded lazily so that ``import fixer4d.pipeline`` stays light.
"""
from __future__ import annotations

import importlib

_EXPORTS = {
    "RunConfig": "config", "SceneConfig": "config", "TrajectoryConfig": "config", "EvalConfig": "config",
    "FORMAT_VERSION": "config", "resolve": "config",
    "parse_set_overrides": "config_tree",
    "RunFolder": "run_folder", "load_scene_for": "run_folder",
    "StageContext": "stages", "StageFailed": "stages",
    "ROW_NAMES": "report",
    "run_pipeline": "run", "run_stages": "run", "open_context": "run",
}

__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    if name in _EXPORTS:
        return getattr(importlib.import_module(f"fixer4d.pipeline.{_EXPORTS[name]}"), name)
    raise AttributeError(f"module 'fixer4d.pipeline' has no attribute {name!r}")
