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
    """Each job is a Ray task with ``cpus_per_job`` CPUs; results come back in job order."""

    name = "ray"

    def __init__(self, address: str | None = None, cpus_per_job: float = 1.0) -> None:
        try:
            import ray
        except ImportError as exc:
            raise BackendUnavailable("the ray executor needs Ray: pip install 'fixer4d[ray]' (or ray), or use "
                                     "--executor local") from exc
        self._ray = ray
        self.cpus_per_job = cpus_per_job
        if not ray.is_initialized():
            # the workers import fixer4d from this checkout, like the driver
            ray.init(address=address, include_dashboard=False, log_to_driver=False,
                     ignore_reinit_error=True, configure_logging=False)

    def map(self, fn: Callable[[Any], Any], jobs: Sequence[Any]) -> list[Any]:
        remote = self._ray.remote(num_cpus=self.cpus_per_job)(fn)
        return self._ray.get([remote.remote(job) for job in jobs])


def make_executor(kind: str, address: str | None = None):
    """The executor a config names ("local" or "ray")."""
    if kind == "local":
        return LocalExecutor()
    if kind == "ray":
        return RayExecutor(address)
    raise BackendUnavailable(f"unknown executor {kind!r}; choose local or ray")


def executor_for(config: ExecutorConfig):
    return make_executor(config.kind, config.ray_address)
