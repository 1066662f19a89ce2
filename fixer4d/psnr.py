"""The one PSNR formula (data range 1), in the bottom layer so that every package can use it:
evaluation's image metrics, training logs and the restore cache's diagnostics."""
from __future__ import annotations

import math

from fixer4d.errors import InputError


def psnr_from_mse(mse: float, max_db: float | None = None) -> float:
    """PSNR in dB for data range 1 from a mean squared error: -10 log10(mse); inf for mse = 0,
    or at most ``max_db`` when given (a cap for reports that cannot hold inf). The one PSNR
    formula: every PSNR in fixer4d (numpy and torch) ends here."""
    mse = float(mse)
    if not (mse >= 0.0 and math.isfinite(mse)):
        raise InputError(f"psnr: mean squared error must be finite and >= 0, got {mse}")
    db = math.inf if mse == 0.0 else -10.0 * math.log10(mse)
    return db if max_db is None else min(db, float(max_db))
