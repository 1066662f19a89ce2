"""fixer4d.restore: reference-guided restoration of rendered clips (docs/design.md §11).

Restorers never render: a RestoreRequest carries every render they need. Built in:
ReferenceWarpRestorer (CPU, deterministic) and LearnedRestorer (a per-scene CNN trained
leave-one-camera-out, restore/learned.py); optional: CogVideoV2VRestorer (diffusers, local
weights, CUDA). ``build_restorer(RestoreConfig(kind=...), weights_dir)`` picks one. RestoreCache
stores restored clips per round; RestoreJobs runs restorers off the caller's thread.
"""
from fixer4d.restore.base import RestoreCancelled, RestoreRequest, RestoreResult, Restorer
from fixer4d.restore.cache import CacheEntry, RestoreCache
from fixer4d.restore.config import LearnedRestorerConfig, RestoreConfig
from fixer4d.restore.factory import build_restorer
from fixer4d.restore.jobs import Job, RestoreJobs
from fixer4d.restore.reference_warp import ReferenceWarpConfig, ReferenceWarpRestorer

__all__ = ["CacheEntry", "Job", "LearnedRestorerConfig", "ReferenceWarpConfig", "ReferenceWarpRestorer", "RestoreCache",
           "RestoreCancelled", "RestoreConfig", "RestoreJobs", "RestoreRequest", "RestoreResult", "Restorer",
           "build_restorer"]
