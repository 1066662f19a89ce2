"""Restoration jobs off the caller's (training or UI) thread.

``RestoreJobs(restorer, cache)`` runs each submitted request through the restorer and writes the
result into the cache. Executors:

* ``"thread"`` (default): a local thread pool. Progress comes from the restorer's progress
  callback; a running job is cancelled between frames (the callback raises RestoreCancelled).
* ``"process"``: a local process pool (the restorer and request are pickled to a worker).
* any ``concurrent.futures.Executor`` (e.g. a distributed one such as a Ray or Dask executor):
  the restore runs there; the cache write happens here.

With a process or user executor, progress jumps from 0 to 1 (callbacks do not cross process
boundaries) and a job already running remotely cannot be interrupted: cancelling it stops the
wait, marks it cancelled and discards its result. In every mode an exception inside one job
marks that job failed with the error text; the others go on.
"""
from __future__ import annotations

import concurrent.futures as cf
import itertools
import threading
import time
import traceback
from dataclasses import dataclass, field
from typing import Any

from fixer4d.errors import InputError
from fixer4d.restore.base import RestoreCancelled, RestoreRequest, RestoreResult, Restorer
from fixer4d.restore.cache import CacheEntry, RestoreCache

QUEUED, RUNNING, DONE, FAILED, CANCELLED = "queued", "running", "done", "failed", "cancelled"
FINAL_STATES = (DONE, FAILED, CANCELLED)
# How often (seconds) a driver thread waiting on a remote executor checks for cancellation.
REMOTE_POLL_S = 0.05


def _restore_remote(restorer: Restorer, request: RestoreRequest) -> RestoreResult:
    """Module-level so that process pools can pickle it."""
    return restorer.restore(request)


@dataclass(eq=False)
class Job:
    """One restoration job. ``status`` is queued/running/done/failed/cancelled; ``progress`` in [0, 1];
    ``error`` is the failure text (``traceback`` the full one); ``entry`` the cache entry when done."""

    id: int
    round: int
    key: str
    status: str = QUEUED
    progress: float = 0.0
    error: str | None = None
    traceback: str | None = None
    entry: CacheEntry | None = None
    seconds: float | None = None
    _cancel: threading.Event = field(default_factory=threading.Event, repr=False)
    _finished: threading.Event = field(default_factory=threading.Event, repr=False)
    _future: cf.Future | None = field(default=None, repr=False)
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

    @property
    def done(self) -> bool:
        return self.status in FINAL_STATES

    @property
    def cancel_requested(self) -> bool:
        return self._cancel.is_set()

    def cancel(self) -> bool:
        """Request cancellation. A queued job is cancelled at once; a running one stops at its next
        frame boundary. Returns False if the job had already finished."""
        with self._lock:
            if self.done:
                return False
            self._cancel.set()
            if self._future is not None and self._future.cancel():
                self._finish(CANCELLED)
        return True

    def wait(self, timeout: float | None = None) -> str:
        """Block until the job finishes (or ``timeout`` seconds pass); returns the status."""
        self._finished.wait(timeout)
        return self.status

    def _start(self) -> bool:
        with self._lock:
            if self._cancel.is_set():
                self._finish(CANCELLED)
                return False
            self.status = RUNNING
            return True

    def _finish(self, status: str) -> None:
        self.status = status
        if status == DONE:
            self.progress = 1.0
        self._finished.set()


class RestoreJobs:
    """A queue of restoration jobs writing into a RestoreCache (see module doc)."""

    def __init__(self, restorer: Restorer, cache: RestoreCache, max_workers: int = 1,
                 executor: str | cf.Executor = "thread") -> None:
        if max_workers < 1:
            raise InputError(f"RestoreJobs: max_workers must be >= 1, got {max_workers}")
        self.restorer = restorer
        self.cache = cache
        self._drivers = cf.ThreadPoolExecutor(max_workers=max_workers, thread_name_prefix="fixer4d-restore")
        self._own_remote = False
        if executor == "thread":
            self._remote: cf.Executor | None = None
        elif executor == "process":
            self._remote = cf.ProcessPoolExecutor(max_workers=max_workers)
            self._own_remote = True
        elif isinstance(executor, cf.Executor):
            self._remote = executor
        else:
            raise InputError(f"RestoreJobs: executor must be 'thread', 'process' or a concurrent.futures.Executor, "
                             f"got {executor!r}")
        self._jobs: list[Job] = []
        self._ids = itertools.count()
        self._lock = threading.Lock()

    def submit(self, request: RestoreRequest, round: int, key: str, meta: dict[str, Any]) -> Job:
        """Queue ``request``; when done its result is cache entry ``key`` of round ``round``."""
        self.cache.entry_dir(round, key)  # validates the key before anything is queued
        with self._lock:
            job = Job(next(self._ids), int(round), key)
            self._jobs.append(job)
            job._future = self._drivers.submit(self._run, job, request, dict(meta))
        return job

    def jobs(self) -> list[Job]:
        """Every job submitted so far, oldest first."""
        with self._lock:
            return list(self._jobs)

    def shutdown(self, wait: bool = True, cancel_pending: bool = False) -> None:
        """Stop accepting jobs; optionally cancel every unfinished one; wait for running ones."""
        if cancel_pending:
            for job in self.jobs():
                job.cancel()
        self._drivers.shutdown(wait=wait)
        if self._own_remote and self._remote is not None:
            self._remote.shutdown(wait=wait, cancel_futures=cancel_pending)

    def __enter__(self) -> "RestoreJobs":
        return self

    def __exit__(self, *exc: object) -> None:
        self.shutdown(wait=True, cancel_pending=exc[0] is not None)

    # ---- worker side -------------------------------------------------------------------
    def _run(self, job: Job, request: RestoreRequest, meta: dict[str, Any]) -> None:
        if not job._start():
            return
        t0 = time.perf_counter()
        try:
            result = self._restore(job, request)
            if job.cancel_requested:
                raise RestoreCancelled()
            meta.setdefault("restorer", {"name": self.restorer.name, "settings": self.restorer.settings()})
            meta["restore_seconds"] = time.perf_counter() - t0
            job.entry = self.cache.write(job.round, job.key, request, result, meta)
            job.seconds = time.perf_counter() - t0
            job._finish(DONE)
        except RestoreCancelled:
            job.seconds = time.perf_counter() - t0
            job._finish(CANCELLED)
        except Exception as exc:  # failure isolation: report it on the job, keep the pool alive
            job.error = f"{type(exc).__name__}: {exc}"
            job.traceback = traceback.format_exc()
            job.seconds = time.perf_counter() - t0
            job._finish(FAILED)

    def _restore(self, job: Job, request: RestoreRequest) -> RestoreResult:
        if self._remote is None:
            def progress(fraction: float) -> None:
                if job.cancel_requested:
                    raise RestoreCancelled()
                job.progress = min(max(float(fraction), 0.0), 1.0)

            return self.restorer.restore(request, progress=progress)
        future = self._remote.submit(_restore_remote, self.restorer, request)
        while not cf.wait([future], timeout=REMOTE_POLL_S).done:
            if job.cancel_requested:
                future.cancel()
                raise RestoreCancelled()
        return future.result()
