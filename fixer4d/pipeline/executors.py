"""Where independent units of work run: in this process (``local``) or on a Ray cluster (``ray``).

An executor maps a top-level function over a list of picklable jobs and returns the results in
order. Segments of a long capture (``segments``) are such jobs. Ray is imported only when asked
for, so `import fixer4d` works without it; a local Ray instance is started when no address is
given, ``address="auto"`` or ``"ray://host:10001"`` joins an existing cluster.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Literal, Sequence

from fixer4d.errors import BackendUnavailable


@dataclass
class ExecutorConfig:
    """Where segments and restore jobs run."""

    kind: Literal["local", "ray"] = "local"
    ray_address: str | None = None  # join an existing cluster ("auto", "ray://HEAD:10001"); None: a local Ray


class LocalExecutor:
    """One job after the other in this process (the default; deterministic and simplest to debug)."""

    name = "local"

    def map(self, fn: Callable[[Any], Any], jobs: Sequence[Any]) -> list[Any]:
        return [fn(job) for job in jobs]


class RayExecutor:
    """Each job is a Ray task run on this process's compute threads (``fixer4d.jit.compute_threads``),
    asking Ray for that many CPUs (at most the largest node's); results come back in job order.

    The thread count travels with the job for speed and for the count of jobs a machine takes on:
    Ray gives a worker OMP_NUM_THREADS=1, which would leave numba's kernels one core. The digits do
    not depend on it: a run's torch computes on ``DIGIT_TORCH_THREADS`` whatever the count
    (fixer4d/threads.py) and numba's kernels sum in a fixed order.
    """

    name = "ray"

    def __init__(self, address: str | None = None, threads: int | None = None) -> None:
        try:
            import ray
        except ImportError as exc:
            raise BackendUnavailable("the ray executor needs Ray: pip install 'fixer4d[ray]' (or ray), or use "
                                     "--executor local") from exc
        from fixer4d.jit import compute_threads

        self._ray = ray
        self.threads = int(threads) if threads is not None else compute_threads()
        if not ray.is_initialized():
            # the workers import fixer4d from this checkout, like the driver
            ray.init(address=address, include_dashboard=False, log_to_driver=False,
                     ignore_reinit_error=True, configure_logging=False)

    def map(self, fn: Callable[[Any], Any], jobs: Sequence[Any]) -> list[Any]:
        # a task that asks for more CPUs than any node has would wait forever; on a smaller node
        # it keeps the driver's thread count anyway (same results, oversubscribed)
        largest = max((n["Resources"].get("CPU", 0.0) for n in self._ray.nodes() if n.get("Alive")), default=1.0)
        remote = self._ray.remote(num_cpus=max(min(float(self.threads), largest), 1e-3))(_run_with_threads)
        return self._ray.get([remote.remote(fn, self.threads, job) for job in jobs])

    def worker_threads(self) -> tuple[int, int]:
        """(torch, numba) thread counts that a task of this executor runs with."""
        return self.map(_thread_counts, [None])[0]


def _thread_counts(_job: Any) -> tuple[int, int]:
    import numba
    import torch

    return torch.get_num_threads(), numba.get_num_threads()


def _run_with_threads(fn: Callable[[Any], Any], threads: int, job: Any) -> Any:
    """``fn(job)`` with torch (and numba, up to its pool size) on ``threads`` threads: a Ray task's
    body (top-level, so workers can unpickle it)."""
    from fixer4d.jit import set_compute_threads
    from fixer4d.threads import torch_threads

    with torch_threads(None):
        set_compute_threads(threads)
        return fn(job)


def make_executor(kind: str, address: str | None = None):
    """The executor a config names ("local" or "ray")."""
    if kind == "local":
        return LocalExecutor()
    if kind == "ray":
        return RayExecutor(address)
    raise BackendUnavailable(f"unknown executor {kind!r}; choose local or ray")


def executor_for(config: ExecutorConfig):
    return make_executor(config.kind, config.ray_address)
