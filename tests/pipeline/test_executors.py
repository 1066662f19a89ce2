"""Executors: local and Ray give the same results; Ray missing is a clear error."""
from __future__ import annotations

import pytest

from fixer4d.pipeline.executors import LocalExecutor, make_executor

from tests.pools import rerun_with_machine_pools


def _square(x):
    return x * x


def test_local_executor_keeps_order():
    assert LocalExecutor().map(_square, [3, 1, 2]) == [9, 1, 4]


def test_unknown_executor_is_refused():
    from fixer4d.errors import BackendUnavailable

    with pytest.raises(BackendUnavailable, match="local or ray"):
        make_executor("slurm")


def test_ray_tasks_run_with_the_driver_thread_counts(request):
    """Ray gives its workers OMP_NUM_THREADS=1; torch's results depend on its thread count, so a
    task must run with the driver's (else a Ray segment trains another model than a local one)."""
    ray = pytest.importorskip("ray", reason="Ray not installed (pip install 'fixer4d[ray]')")
    if rerun_with_machine_pools(request):  # its workers' numba pools are the driver's
        return
    import torch

    from fixer4d.pipeline.executors import RayExecutor

    try:
        ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, configure_logging=False,
                 runtime_env={"env_vars": {"OMP_NUM_THREADS": "1"}})
        assert RayExecutor(threads=2).worker_threads() == (2, 2)
        assert RayExecutor(threads=1).worker_threads() == (1, 1)
        assert RayExecutor().threads == torch.get_num_threads()
    finally:
        ray.shutdown()


def test_ray_tasks_fit_a_node_smaller_than_the_driver_threads():
    """A task asks for at most the largest node's CPUs (else it would never be scheduled) and
    still runs with the driver's thread count."""
    ray = pytest.importorskip("ray", reason="Ray not installed (pip install 'fixer4d[ray]')")
    from fixer4d.pipeline.executors import RayExecutor

    try:
        ray.init(num_cpus=1, include_dashboard=False, log_to_driver=False, configure_logging=False)
        assert RayExecutor(threads=2).worker_threads()[0] == 2
    finally:
        ray.shutdown()


def test_ray_runs_give_the_local_results(tmp_path, stage_cache):
    """On a local Ray instance (2 CPUs): segments as Ray tasks (the shared-static schedule: the first
    segment, then the other on top of its static rows), and stage 2's restore jobs as Ray tasks,
    give exactly the rows of the local executor (the pipeline is deterministic)."""
    ray = pytest.importorskip("ray", reason="Ray not installed (pip install 'fixer4d[ray]')")
    from fixer4d.pipeline.run import run_pipeline
    from pipeline_tiny import tiny_config

    segmented = {"segments.frames": 3, "segments.overlap": 2, "segments.share_static": True, "stage2.rounds": 0,
                 "baseline_sparse": False, "eval.restoration_rows": False, "init_frame_stride": 1, "eval.stride": 1}
    restoring = {"baseline_sparse": False, "eval.restoration_rows": False, "eval.matched_row": False}
    local_seg = run_pipeline(tiny_config(**segmented), tmp_path / "local_seg", progress=False)
    local_s2 = run_pipeline(tiny_config(**restoring), tmp_path / "local_s2", progress=False, stage_cache=stage_cache)
    try:
        ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, configure_logging=False,
                 runtime_env={"env_vars": {"OMP_NUM_THREADS": "1"}})
        ray_seg = run_pipeline(tiny_config(**segmented, **{"executor.kind": "ray"}), tmp_path / "ray_seg",
                               progress=False)
        ray_s2 = run_pipeline(tiny_config(**restoring, **{"executor.kind": "ray"}), tmp_path / "ray_s2",
                              progress=False, stage_cache=stage_cache)
    finally:
        ray.shutdown()

    def strip(rows):
        return [{k: v for k, v in r.items() if k != "seconds"} for r in rows]

    assert strip(ray_seg["rows"]) == strip(local_seg["rows"])
    assert strip(ray_s2["rows"]) == strip(local_s2["rows"])
    assert (tmp_path / "ray_s2" / "model_final.ply").read_bytes() == (tmp_path / "local_s2" / "model_final.ply").read_bytes()
