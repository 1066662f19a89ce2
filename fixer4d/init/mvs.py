"""Multi-view depth for one timestamp: pick a DepthEstimator by name (``make_estimator``).

- "planesweep" (built in): ``PlaneSweepMVS``, coarse-to-fine plane-sweep stereo with ZNCC
  (fixer4d.init.plane_sweep; its cost in matching_cost, regions and tiles in sweep_regions,
  the geometric check in consistency, the depth ranges in depth_range);
- "mvsanywhere" (optional CUDA backend): ``MVSAnywhereEstimator`` around the ``mvsanywhere``
  package and local weights (fixer4d.init.mvsanywhere).

Both follow fixer4d.init.depth_estimator: V images + cameras -> one DepthResult per view.
"""
from __future__ import annotations

from fixer4d.errors import InputError
from fixer4d.init.depth_estimator import DepthEstimator
from fixer4d.init.mvsanywhere import MVSAnywhereConfig, MVSAnywhereEstimator
from fixer4d.init.plane_sweep import PlaneSweepConfig, PlaneSweepMVS


def make_estimator(name: str, planesweep: PlaneSweepConfig | None = None,
                   mvsanywhere: MVSAnywhereConfig | None = None) -> DepthEstimator:
    """"planesweep" (built in) or "mvsanywhere" (optional package + local weights)."""
    if name == "planesweep":
        return PlaneSweepMVS(planesweep)
    if name == "mvsanywhere":
        return MVSAnywhereEstimator(mvsanywhere)
    raise InputError(f"unknown depth estimator {name!r}; choose planesweep or mvsanywhere")
