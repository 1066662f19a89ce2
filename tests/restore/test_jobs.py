"""RestoreJobs: status, progress, cancellation, failure isolation, executors."""
from __future__ import annotations

import concurrent.futures as cf
import threading

import numpy as np
import pytest

from fixer4d.errors import InputError
from fixer4d.restore.base import RestoreResult
from fixer4d.restore.cache import RestoreCache
from fixer4d.restore.jobs import CANCELLED, DONE, FAILED, RestoreJobs
from fixer4d.restore.reference_warp import ReferenceWarpRestorer

from .conftest import tiny_request


class GatedRestorer:
    """Test double: waits on an event between frames, reports progress, fails when told to."""

    name = "gated"

    def __init__(self) -> None:
        self.gate = threading.Event()
        self.started = threading.Event()
        self.fail_on_time: float | None = None
        self.frames_done = 0

    def settings(self) -> dict:
        return {"gated": True}

    def restore(self, request, progress=None):
        self.started.set()
        F = request.num_frames
        for k in range(F):
            assert self.gate.wait(10.0), "test gate never opened"
            if request.time == self.fail_on_time:
                raise ValueError(f"boom at t={request.time}")
            self.frames_done += 1
            if progress is not None:
                progress((k + 1) / F)
        conf = np.ones(request.alpha.shape, np.float32)
        return RestoreResult(request.rgb.copy(), conf, np.ones(F, np.float32))


def _request(time: float = 0.25, frames: int = 3):
    r = tiny_request(frames=frames)
    r.time = time
    return r


def test_job_runs_off_thread_and_lands_in_cache(tmp_path):
    cache = RestoreCache(tmp_path)
    with RestoreJobs(ReferenceWarpRestorer(), cache) as jobs:
        job = jobs.submit(_request(), 0, "t0003_0-1", {"step": 10})
        assert job.wait(30) == DONE
    assert job.progress == 1.0 and job.error is None and job.seconds > 0
    assert job.entry is not None and cache.has(0, "t0003_0-1")
    meta = cache.get(0, "t0003_0-1").meta
    assert meta["step"] == 10 and meta["restorer"]["name"] == "reference_warp"
    assert meta["restorer"]["settings"]["temporal_radius"] == 1
    assert jobs.jobs() == [job]


def test_status_and_progress_follow_the_restorer(tmp_path):
    restorer = GatedRestorer()
    jobs = RestoreJobs(restorer, RestoreCache(tmp_path))
    job = jobs.submit(_request(), 0, "a", {})
    assert restorer.started.wait(10)
    assert job.status == "running" and job.progress == 0.0
    restorer.gate.set()
    assert job.wait(10) == DONE and job.progress == 1.0
    jobs.shutdown()


def test_queued_job_cancels_immediately_running_job_between_frames(tmp_path):
    restorer = GatedRestorer()
    cache = RestoreCache(tmp_path)
    jobs = RestoreJobs(restorer, cache, max_workers=1)
    running = jobs.submit(_request(frames=4), 0, "running", {})
    queued = jobs.submit(_request(), 0, "queued", {})
    assert restorer.started.wait(10)
    assert queued.status == "queued"
    assert queued.cancel() and queued.status == CANCELLED  # at once, without waiting for the worker
    assert running.cancel()
    restorer.gate.set()
    assert running.wait(10) == CANCELLED
    assert restorer.frames_done == 1  # stopped at the first frame boundary after the request
    assert not cache.has(0, "running") and not cache.has(0, "queued")
    assert not running.cancel()  # already finished
    jobs.shutdown()


def test_failure_is_isolated(tmp_path):
    restorer = GatedRestorer()
    restorer.fail_on_time = 0.5
    restorer.gate.set()
    cache = RestoreCache(tmp_path)
    with RestoreJobs(restorer, cache, max_workers=2) as jobs:
        ok1 = jobs.submit(_request(0.25), 0, "ok1", {})
        bad = jobs.submit(_request(0.5), 0, "bad", {})
        ok2 = jobs.submit(_request(0.75), 0, "ok2", {})
        statuses = [j.wait(10) for j in (ok1, bad, ok2)]
    assert statuses == [DONE, FAILED, DONE]
    assert bad.error == "ValueError: boom at t=0.5" and "Traceback" in bad.traceback
    assert cache.has(0, "ok1") and cache.has(0, "ok2") and not cache.has(0, "bad")


def test_cache_write_failure_is_a_job_failure(tmp_path):
    blocker = tmp_path / "cache"
    blocker.write_text("not a directory")
    restorer = GatedRestorer()
    restorer.gate.set()
    with RestoreJobs(restorer, RestoreCache(blocker)) as jobs:
        job = jobs.submit(_request(), 0, "a", {})
        assert job.wait(10) == FAILED
    assert job.error


def test_user_supplied_executor(tmp_path):
    restorer = GatedRestorer()
    restorer.gate.set()
    remote = cf.ThreadPoolExecutor(max_workers=1)  # stands in for a distributed executor
    with RestoreJobs(restorer, RestoreCache(tmp_path), executor=remote) as jobs:
        job = jobs.submit(_request(), 1, "remote", {})
        assert job.wait(10) == DONE and job.progress == 1.0
    assert job.entry.round == 1
    remote.submit(lambda: None).result()  # the caller's executor is not shut down by RestoreJobs
    remote.shutdown()


def test_process_pool(tmp_path):
    cache = RestoreCache(tmp_path)
    with RestoreJobs(ReferenceWarpRestorer(), cache, executor="process") as jobs:
        job = jobs.submit(_request(), 0, "proc", {})
        assert job.wait(120) == DONE, job.error
    local = ReferenceWarpRestorer().restore(_request())
    np.testing.assert_allclose(cache.get(0, "proc").rgb(), local.rgb, atol=0.5 / 255 + 1e-6)


def test_bad_arguments(tmp_path):
    with pytest.raises(InputError):
        RestoreJobs(ReferenceWarpRestorer(), RestoreCache(tmp_path), max_workers=0)
    with pytest.raises(InputError):
        RestoreJobs(ReferenceWarpRestorer(), RestoreCache(tmp_path), executor="ray")
    with RestoreJobs(ReferenceWarpRestorer(), RestoreCache(tmp_path)) as jobs, pytest.raises(InputError):
        jobs.submit(_request(), 0, "../escape", {})
