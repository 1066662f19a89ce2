"""fixer4d.model: spacetime Gaussians (spacetime.py; view-dependent colour sh.py, initial extents
initial_scales.py), their snapshot (snapshot.py) and I/O (io.py).

Names are resolved lazily so that `import fixer4d.cli.export` (the `export` verb) stays light.
"""
from __future__ import annotations

import importlib
from typing import Any

_LAZY = {
    "Snapshot": "fixer4d.model.snapshot",
    "ModelConfig": "fixer4d.model.spacetime",
    "SpacetimeGaussians": "fixer4d.model.spacetime",
    "save_ply": "fixer4d.model.io",
    "load_ply": "fixer4d.model.io",
    "save_npz": "fixer4d.model.io",
    "load_npz": "fixer4d.model.io",
    "save_model": "fixer4d.model.io",
    "load_model": "fixer4d.model.io",
}

__all__ = sorted(_LAZY)


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'fixer4d.model' has no attribute {name!r}")
