"""tests/pools.py: an xdist worker's share of the thread pools, and the machine's pools for a child."""
from __future__ import annotations

from fixer4d import cpus

from tests import pools


def test_a_worker_splits_the_pools_and_a_child_gets_the_machines_back(monkeypatch):
    monkeypatch.setattr(cpus, "usable_cpus", lambda root=None: 2)
    env = {"PYTEST_XDIST_WORKER": "gw1", "PYTEST_XDIST_WORKER_COUNT": "2", "PATH": "/bin"}
    pools.split_pools(environ=env)
    assert env["NUMBA_NUM_THREADS"] == env["OMP_NUM_THREADS"] == "1"
    assert pools.machine_pools_env(env) == {"PATH": "/bin"}


def test_the_users_own_pool_sizes_win_and_stay_for_the_child(monkeypatch):
    monkeypatch.setattr(cpus, "usable_cpus", lambda root=None: 2)
    env = {"PYTEST_XDIST_WORKER_COUNT": "2", "OMP_NUM_THREADS": "2"}
    pools.split_pools(keep={"OMP_NUM_THREADS"}, environ=env)
    assert env["OMP_NUM_THREADS"] == "2" and env["NUMBA_NUM_THREADS"] == "1"
    assert pools.machine_pools_env(env) == {"OMP_NUM_THREADS": "2"}


def test_outside_xdist_nothing_is_split():
    env = {"PATH": "/bin"}
    pools.split_pools(environ=env)
    assert env == {"PATH": "/bin"}


def test_workers_that_share_the_cpus_get_a_share_each_and_at_least_one_thread(monkeypatch):
    monkeypatch.setattr(cpus, "usable_cpus", lambda root=None: 4)
    assert pools.worker_thread_env("2") == {"NUMBA_NUM_THREADS": "2", "OMP_NUM_THREADS": "2"}
    assert pools.worker_thread_env(3) == {"NUMBA_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"}
    assert pools.worker_thread_env(16)["NUMBA_NUM_THREADS"] == "1"
    for alone in (None, 1, "1", "0", "many"):  # one process (or no count) keeps the defaults
        assert pools.worker_thread_env(alone) == {}
