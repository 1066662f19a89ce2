"""Shared by the numerics property tests: what counts as a finite result."""
from __future__ import annotations

import math

import numpy as np
import torch


def finite(x) -> bool:
    """True when every number in ``x`` (tensor, array, float, or a dict/list/tuple of them) is finite."""
    if torch.is_tensor(x):
        return bool(torch.isfinite(x).all())
    if isinstance(x, np.ndarray):
        return bool(np.isfinite(x).all()) if x.dtype.kind in "fc" else True
    if isinstance(x, float):
        return math.isfinite(x)
    if isinstance(x, dict):
        return all(v is None or finite(v) for v in x.values())
    if isinstance(x, (tuple, list)):
        return all(finite(v) for v in x)
    return True
