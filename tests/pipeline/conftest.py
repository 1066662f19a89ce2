"""Shared fixtures of the pipeline tests: a tiny configuration and one finished tiny run.

Every run here shares one StageCache, so a test that needs an init or a stage-1 model already
computed by another gets it copied instead of recomputed (the suite stays short)."""
from __future__ import annotations

import pytest

from pipeline_tiny import run_spied, tiny_config


@pytest.fixture(scope="session")
def stage_cache(tmp_path_factory):
    return tmp_path_factory.mktemp("stage_cache")


@pytest.fixture(scope="session")
def tiny_spied_run(tmp_path_factory, stage_cache):
    """(run folder, report, HeldOutSpy) of the whole pipeline on the tiny scene, every held-out
    read recorded."""
    run_dir = tmp_path_factory.mktemp("run") / "tiny"
    report, spy = run_spied(tiny_config(), run_dir, stage_cache)
    return run_dir, report, spy


@pytest.fixture(scope="session")
def tiny_run(tiny_spied_run):
    """(run folder, report) of the whole pipeline on the tiny scene."""
    return tiny_spied_run[:2]


@pytest.fixture(scope="session")
def one_field_run(tmp_path_factory, stage_cache):
    """(run folder, report) of the tiny pipeline with one stage-1 field (``training.fields=1``):
    the base of the benches that study one field's training."""
    run_dir = tmp_path_factory.mktemp("run") / "one_field"
    report, _ = run_spied(tiny_config(**{"training.fields": 1}), run_dir, stage_cache)
    return run_dir, report
