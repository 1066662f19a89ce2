"""Which layout a PLY without fixer4d's header has: STGS lite, static 3DGS, or a refusal naming
the fields found (``fixer4d.model.io.load_ply`` dispatches here)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from fixer4d.errors import InputError
from fixer4d.model.formats import ply3dgs, stgs_reference
from fixer4d.model.spacetime import SpacetimeGaussians


def read_foreign_ply(vertex: np.ndarray, path: Path) -> SpacetimeGaussians:
    """A model from the ``vertex`` rows of another tool's PLY: any STGS time field (trbf_*,
    motion_*, omega_*) -> STGS lite (``stgs_reference``); else the 3DGS fields -> a static
    model (``ply3dgs``); else InputError listing the fields the file has."""
    names = set(vertex.dtype.names or ())
    if stgs_reference.is_reference(names):
        return stgs_reference.read_reference(vertex, path)
    if ply3dgs.is_3dgs(names):
        return ply3dgs.read_3dgs(vertex, path)
    shown = sorted(names)
    listing = ", ".join(shown[:24]) + (f", ... ({len(shown)} in all)" if len(shown) > 24 else "")
    raise InputError(f"{path}: unknown Gaussian PLY layout (fields: {listing or 'none'}); fixer4d reads its own PLYs, "
                     "STGS lite PLYs (x y z trbf_* motion_* omega_* f_dc_0..2 ...) and 3DGS PLYs "
                     "(x y z f_dc_0..2 [f_rest_*] opacity scale_0..2 rot_0..3)")
