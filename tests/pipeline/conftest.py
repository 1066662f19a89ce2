"""Shared fixtures of the pipeline tests: a tiny configuration and one finished tiny run.

Every run here shares one StageCache, so a test that needs an init or a stage-1 model already
computed by another gets it copied instead of recomputed (the suite stays short)."""
from __future__ import annotations

import pytest

from pipeline_tiny import tiny_config


@pytest.fixture(scope="session")
def stage_cache(tmp_path_factory):
    return tmp_path_factory.mktemp("stage_cache")


@pytest.fixture(scope="session")
def tiny_run(tmp_path_factory, stage_cache):
    """(run folder, report) of the whole pipeline on the tiny scene."""
    from fixer4d.pipeline.run import run_pipeline

    run_dir = tmp_path_factory.mktemp("run") / "tiny"
    report = run_pipeline(tiny_config(), run_dir, progress=False, stage_cache=stage_cache)
    return run_dir, report
