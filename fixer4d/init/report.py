"""What ``run_init`` and the decomposed init share: stage timers and the init report writer
(``init_report.json``)."""
from __future__ import annotations

import time
from pathlib import Path
from typing import Any

from fixer4d.atomic import write_json

REPORT_NAME = "init_report.json"


class Timer:
    """Accumulates wall time per stage, and the process CPU time of every thread since the
    previous ``add`` (a load-independent measure when cores are shared)."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = {}
        self.cpu_seconds: dict[str, float] = {}
        self._cpu = time.process_time()

    def add(self, stage: str, t0: float) -> float:
        dt = time.perf_counter() - t0
        cpu = time.process_time()
        self.seconds[stage] = self.seconds.get(stage, 0.0) + dt
        self.cpu_seconds[stage] = self.cpu_seconds.get(stage, 0.0) + cpu - self._cpu
        self._cpu = cpu
        return dt


# Stages whose time counts as preparing the init (loading, writing and quality checks do not;
# a pose *check* with given poses is a diagnostic, not part of preparing the clouds).
PREP_STAGES = ("depth_range", "sparse", "mvs", "fusion", "masks", "static_median", "motion", "evidence")


def finish_report(report: dict[str, Any], timer: Timer, t_start: float, config, estimator,
                  out_dir: Path) -> None:
    """Add seconds (wall, CPU, "preparation" = PREP_STAGES (+ poses when SfM gives them)), the
    estimator name and the config to ``report`` and write ``out_dir/init_report.json``."""
    prep_stages = PREP_STAGES + (("poses",) if config.poses.source == "sfm" else ())
    seconds = dict(timer.seconds)
    seconds["preparation"] = sum(seconds.get(k, 0.0) for k in prep_stages)
    seconds["total"] = time.perf_counter() - t_start
    report["seconds"] = seconds
    cpu = dict(timer.cpu_seconds)
    cpu["preparation"] = sum(cpu.get(k, 0.0) for k in prep_stages)
    report["cpu_seconds"] = cpu
    if estimator is not None:
        report["estimator"] = estimator.name
    report["config"] = config.to_dict()
    write_json(out_dir / REPORT_NAME, report)
