"""Executors: local and Ray give the same results; Ray missing is a clear error."""
from __future__ import annotations

import pytest

from fixer4d.pipeline.executors import LocalExecutor, make_executor


def _square(x):
    return x * x


def test_local_executor_keeps_order():
    assert LocalExecutor().map(_square, [3, 1, 2]) == [9, 1, 4]


def test_unknown_executor_is_refused():
    from fixer4d.errors import BackendUnavailable

    with pytest.raises(BackendUnavailable, match="local or ray"):
        make_executor("slurm")


def test_ray_segmented_run_equals_local(tmp_path, stage_cache):
    """The same segmented tiny run on the local executor and on a local Ray instance (2 CPUs)."""
    ray = pytest.importorskip("ray", reason="Ray not installed (pip install 'fixer4d[ray]')")
    from fixer4d.pipeline.run import run_pipeline
    from pipeline_tiny import tiny_config

    overrides = {"segments.frames": 3, "segments.overlap": 2, "stage2.rounds": 0, "baseline_sparse": False,
                 "eval.restoration_rows": False, "init_frame_stride": 1, "eval.stride": 1}
    local = run_pipeline(tiny_config(**overrides), tmp_path / "local", progress=False)
    try:
        ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, configure_logging=False,
                 runtime_env={"env_vars": {"OMP_NUM_THREADS": "1"}})
        remote = run_pipeline(tiny_config(**overrides, **{"segments.executor": "ray"}), tmp_path / "ray",
                              progress=False)
    finally:
        ray.shutdown()
    strip = lambda rows: [{k: v for k, v in r.items() if k != "seconds"} for r in rows]  # noqa: E731
    assert strip(remote["rows"]) == strip(local["rows"])
