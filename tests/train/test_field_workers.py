"""train.field_workers: how many workers, and what reaches the caller when a worker fails."""
from __future__ import annotations

import os
from pathlib import Path

import pytest


def raising_trainer(message: str, field: int, directory: Path):
    """A recipe's function whose field cannot be built (the caller's input is wrong)."""
    from fixer4d.errors import InputError

    raise InputError(f"{message} (field {field})")


def dying_trainer(field: int, directory: Path):
    """A recipe's function whose worker dies without a word, as one the kernel kills."""
    os._exit(3)


def test_worker_count_is_one_per_cpu_at_most_one_per_field(monkeypatch):
    import fixer4d.train.field_workers as fw
    from fixer4d.train.config import TrainingConfig
    from fixer4d.train.field_workers import worker_count

    monkeypatch.setattr(fw, "cpu_budget", lambda: 2)
    assert worker_count(TrainingConfig(), 4) == 2
    assert worker_count(TrainingConfig(), 1) == 1
    assert worker_count(TrainingConfig(field_workers=3), 4) == 3
    assert worker_count(TrainingConfig(field_workers=3), 2) == 2
    assert worker_count(TrainingConfig(field_workers=1), 4) == 1


def test_the_cpu_budget_is_the_threads_an_executor_grants(monkeypatch):
    import fixer4d.cpus
    import fixer4d.jit
    from fixer4d.train.field_workers import cpu_budget

    monkeypatch.setattr(fixer4d.cpus, "usable_cpus", lambda root=None: 8)
    monkeypatch.setattr(fixer4d.jit, "compute_threads", lambda: 2)
    assert cpu_budget() == 2
    monkeypatch.setattr(fixer4d.cpus, "usable_cpus", lambda root=None: 1)
    assert cpu_budget() == 1


def test_worker_count_is_one_on_cuda(monkeypatch):
    import fixer4d.train.device
    from fixer4d.train.config import TrainingConfig
    from fixer4d.train.field_workers import worker_count

    monkeypatch.setattr(fixer4d.train.device, "device_kind", lambda device, backend: "cuda")
    assert worker_count(TrainingConfig(field_workers=4), 4) == 1


def test_fields_go_to_workers_only_where_a_worker_can_load_the_scene(monkeypatch):
    import fixer4d.train.field_workers as fw
    from fixer4d.train.config import TrainingConfig

    monkeypatch.setattr(fw, "cpu_budget", lambda: 2)
    recipe, workers = fw.plan_workers(TrainingConfig(), 2, True, "pkg.mod:fn", {"a": 1}, 3)
    assert workers == 2 and recipe == fw.FieldRecipe("pkg.mod:fn", ({"a": 1}, 3))
    assert fw.plan_workers(TrainingConfig(), 2, False, "pkg.mod:fn") == (None, 1)
    assert fw.plan_workers(TrainingConfig(field_workers=1), 2, True, "pkg.mod:fn") == (None, 1)


def test_a_negative_worker_count_is_refused():
    from fixer4d.errors import InputError
    from fixer4d.train.config import TrainingConfig

    with pytest.raises(InputError, match="field_workers"):
        TrainingConfig(field_workers=-1)


def test_a_workers_error_reaches_the_caller_with_its_field(tmp_path):
    from fixer4d.errors import InputError
    from fixer4d.train.field_workers import FieldRecipe, train_in_workers
    from fixer4d.train.fields import save_field

    recipe = FieldRecipe(f"{__name__}:raising_trainer", ("no such camera",))
    jobs = [(0, tmp_path / "f0"), (1, tmp_path / "f1")]
    with pytest.raises(InputError, match=r"stage 1, field [12]: InputError: no such camera \(field [01]\)"):
        train_in_workers(recipe, jobs, 2, "stage 1", save_field, progress=False)


def test_a_worker_that_dies_says_how_to_resume(tmp_path):
    from fixer4d.errors import Fixer4DError
    from fixer4d.train.field_workers import FieldRecipe, train_in_workers
    from fixer4d.train.fields import save_field

    recipe = FieldRecipe(f"{__name__}:dying_trainer")
    with pytest.raises(Fixer4DError, match="exit code 3.*resume from its checkpoints"):
        train_in_workers(recipe, [(0, tmp_path / "f0"), (1, tmp_path / "f1")], 2, "stage 1", save_field,
                         progress=False)


def test_the_budget_inside_a_run_is_the_compute_threads_not_torchs_one():
    """A run's torch computes on DIGIT_TORCH_THREADS (1): the fields' workers still get every
    granted core."""
    import numba
    import torch

    from fixer4d.cpus import usable_cpus
    from fixer4d.jit import compute_threads, set_compute_threads
    from fixer4d.threads import digit_threads
    from fixer4d.train.field_workers import cpu_budget

    before, torch_before = compute_threads(), torch.get_num_threads()
    granted = min(2, numba.config.NUMBA_NUM_THREADS, usable_cpus())
    try:
        set_compute_threads(granted)
        with digit_threads():
            assert torch.get_num_threads() == 1
            assert cpu_budget() == granted
    finally:
        set_compute_threads(before)
        torch.set_num_threads(torch_before)
