"""Fixtures shared by every test folder.

tiny_scene: the bundled 8-camera, 64x48, 4-frame synthetic scene (assets/scenes/tiny.json).
panoptic_dir: the real Panoptic basketball subset in ../shared/data (skips when absent).
benchmark_script(name): a script of benchmarks/ loaded as a module (registered while in use).
"""
from __future__ import annotations

import importlib.util
import os
import sys
from pathlib import Path

import pytest

# Read before fixer4d's import sets its own defaults: the variables the user set.
_POOLS_SET_BY_THE_USER = {key for key in ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS") if key in os.environ}

import fixer4d  # noqa: E402,F401  (first: sets the OpenMP wait policy before any test imports torch)
from fixer4d.cpus import usable_cpus  # noqa: E402

from tests.pools import split_pools  # noqa: E402

split_pools(keep=_POOLS_SET_BY_THE_USER)  # before torch or numba loads (importing fixer4d loads neither): tests/pools.py

REPO_ROOT = Path(__file__).resolve().parents[1]
PANOPTIC_DIR = Path(__file__).resolve().parents[1].parent / "shared/data/panoptic_basketball"


@pytest.hookimpl(optionalhook=True)
def pytest_xdist_auto_num_workers(config):
    """``-n auto``: one worker per CPU this process may use (the cgroup quota counted), where
    xdist's own count would start one per host CPU on a CI runner's quota."""
    return usable_cpus()


@pytest.fixture(scope="session", autouse=True)
def _auto_device_trains_on_the_cpu():
    """Trainers whose config leaves ``training.device`` at "auto" train on the CPU here, on a machine
    with a GPU too: the figures the tests hold were measured on the CPU, and CUDA runs are not
    bit-reproducible. A test of the GPU path asks for "cuda" by name."""
    import fixer4d.train.trainer as trainer_module

    resolve = trainer_module.training_device
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(trainer_module, "training_device",
                      lambda device, backend: resolve("cpu" if device == "auto" else device, backend))
        yield


@pytest.fixture(scope="session")
def tiny_scene():
    """SyntheticScene of assets/scenes/tiny.json (read-only: share it, do not mutate it)."""
    from fixer4d.scene.synthetic import SyntheticScene

    return SyntheticScene("tiny")


@pytest.fixture(scope="session")
def panoptic_dir() -> Path:
    """The Panoptic basketball folder (Dynamic3DGaussians layout), read-only."""
    if not (PANOPTIC_DIR / "train_meta.json").is_file():
        pytest.skip(f"real-data test skipped: the Panoptic basketball subset is not at {PANOPTIC_DIR} "
                    f"(expected ../shared/data/panoptic_basketball next to the repository)")
    return PANOPTIC_DIR


def load_benchmark(name: str):
    """benchmarks/<name>.py as a module named ``name``, registered in sys.modules (dataclasses
    look their module up while a class is built); the caller unregisters it."""
    spec = importlib.util.spec_from_file_location(name, REPO_ROOT / "benchmarks" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def benchmark_script():
    """``benchmark_script(name)`` -> the module of benchmarks/<name>.py, unregistered afterwards."""
    loaded: list[str] = []

    def load(name: str):
        loaded.append(name)
        return load_benchmark(name)

    yield load
    for name in loaded:
        sys.modules.pop(name, None)


# the tests that compare bytes with the fingerprint (a skip: not compared here), by what they compare
_FINGERPRINT_TESTS = {"test_portable_mode_gives_the_same_bytes_under_every_emulated_host": "probe",
                      "test_a_tiny_pipeline_gives_the_same_model_and_report_on_two_emulated_hosts": "tiny pipeline"}


@pytest.hookimpl(trylast=True)
def pytest_terminal_summary(terminalreporter):
    """The host's CPU and what became of the cross-host byte checks (tests/numerics/fingerprint.json),
    at the end of the log where a CI excerpt keeps it: which CPUs a fingerprint was compared on."""
    from fixer4d.bench.machine import cpu_topology

    cpu = cpu_topology()
    outcomes = []
    for outcome in ("passed", "failed", "skipped"):
        for report in terminalreporter.stats.get(outcome, []):
            name = getattr(report, "nodeid", "").rsplit("::", 1)[-1]
            if name in _FINGERPRINT_TESTS and getattr(report, "when", "call") in ("call", "setup"):
                outcomes.append(f"{_FINGERPRINT_TESTS[name]} {outcome}")
    terminalreporter.write_line(
        f"host: {cpu.get('cpu')} (family {cpu.get('cpu_family')}, model {cpu.get('model')}; "
        f"{' '.join(cpu.get('vector_extensions', []))}); fingerprint (cross-host bytes): {', '.join(outcomes) or 'not run'}")
