"""fixer4d.init: geometric initialization of per-frame point clouds.

Poses (given, or pycolmap SfM at t = 0), then per frame either the sparse COLMAP baseline
(SIFT + triangulation with fixed poses) or multi-view depth (plane sweep or MVSAnywhere) fused
into a dense cloud (Eq. 1-2). ``run_init`` drives it and writes ``frame_XXXX.ply`` files plus
``init_report.json``. ``run_init`` and ``InitConfig`` load lazily (they pull in torch), so that
`fixer4d --help` stays fast.
"""
from fixer4d.init.cloud import FrameCloud, load_frame_clouds, merge_clouds, save_frame_clouds
from fixer4d.init.report import REPORT_NAME

__all__ = ["FrameCloud", "save_frame_clouds", "load_frame_clouds", "merge_clouds", "InitConfig", "run_init",
           "METHODS", "REPORT_NAME"]

_LAZY = {"InitConfig", "run_init", "METHODS"}


def __getattr__(name: str):
    if name in _LAZY:
        from fixer4d.init import run

        return getattr(run, name)
    raise AttributeError(f"module 'fixer4d.init' has no attribute {name!r}")
