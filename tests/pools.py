"""Thread pools of the test processes under pytest-xdist (``make test`` runs ``-n auto``).

Each worker computes on its share of the usable CPUs (numba's and OpenMP's pools sized by
``worker_thread_env``): a worker whose pools each took every CPU would oversubscribe
the machine at every parallel region. The conftest sets the split before torch or numba loads and
names the variables it set in ``SPLIT_POOLS_VAR``. A test whose subject is the thread count (or a
process it starts, whose digits follow its own count) asks for the machine's pools here.
"""
from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Collection

from fixer4d import cpus

SPLIT_POOLS_VAR = "FIXER4D_TEST_SPLIT_POOLS"
XDIST_VARS = ("PYTEST_XDIST_WORKER", "PYTEST_XDIST_WORKER_COUNT", "PYTEST_XDIST_TESTRUNUID")


def worker_thread_env(workers: int | str | None) -> dict[str, str]:
    """Thread-pool sizes for one of ``workers`` processes that share the usable CPUs
    (``fixer4d.cpus.usable_cpus``) evenly, at least one thread each; empty for ``workers`` None or
    below 2 (one process keeps the libraries' defaults)."""
    try:
        count = int(workers) if workers is not None else 1
    except ValueError:
        return {}
    if count < 2:
        return {}
    n = str(max(1, cpus.usable_cpus() // count))
    return {"NUMBA_NUM_THREADS": n, "OMP_NUM_THREADS": n}


def split_pools(keep: Collection[str] = (), environ: dict[str, str] | None = None) -> None:
    """In an xdist worker, size this process's pools to its share of the CPUs; the variables in
    ``keep`` (the user's own NUMBA_NUM_THREADS / OMP_NUM_THREADS) win. Call before torch or numba
    loads."""
    environ = os.environ if environ is None else environ
    share = {key: value for key, value in worker_thread_env(environ.get("PYTEST_XDIST_WORKER_COUNT")).items()
             if key not in keep}
    if share:
        environ.update(share)
        environ[SPLIT_POOLS_VAR] = ",".join(sorted(share))


def pools_are_split() -> bool:
    """Whether this process runs on a worker's share of the CPUs."""
    return bool(os.environ.get(SPLIT_POOLS_VAR))


def machine_pools_env(environ: dict[str, str] | None = None) -> dict[str, str]:
    """A copy of ``environ`` (default os.environ) for a child process with the machine's pools:
    the worker's split and xdist's worker variables removed."""
    env = dict(os.environ if environ is None else environ)
    for key in env.pop(SPLIT_POOLS_VAR, "").split(","):
        env.pop(key, None)
    for key in XDIST_VARS:
        env.pop(key, None)
    return env


def rerun_with_machine_pools(request, timeout: float = 900) -> bool:
    """For a test that needs the machine's pools in its own process (``request``: its pytest
    request): where this process's pools are split, run the test again in a fresh pytest process
    with the machine's pools, assert that it passed and return True (the caller returns); else
    False (the test runs here)."""
    if not pools_are_split():
        return False
    done = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:xdist", "-p", "no:cacheprovider",
                           request.node.nodeid], cwd=request.config.rootpath, env=machine_pools_env(),
                          capture_output=True, text=True, timeout=timeout)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-2000:]
    assert " passed" in done.stdout, done.stdout[-3000:]  # not skipped there
    return True
