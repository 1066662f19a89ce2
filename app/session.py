"""Background work for the viewer: live training and restoration jobs, talking to the UI
through mailboxes so the UI thread never blocks on them (docs/design.md §16).

- ``Mailbox``: a single-slot, latest-value-wins handoff (a newer model replaces an unread one).
- ``TrainingSession``: runs ``Trainer.step()`` in a thread (after a setup function, e.g. init +
  model construction, that reports its progress), publishes the model's raw parameters every
  few steps (and at most every PUBLISH_MIN_S) and a loss record every step, pauses/resumes.
  The trainer never waits for the UI: the UI reads what was published when it draws.
- ``live_stage1_trainer``: live training through the pipeline's stage functions (the same
  init, config, schedule, caps and model terms as ``fixer4d run``'s stage 1).
- ``RestoreQueue``: renders the request for (trajectory, frame) on a worker thread with an
  injected render function, then submits it to ``fixer4d.restore.jobs.RestoreJobs``; finished
  clips land in the cache through the jobs' own writer.
"""
from __future__ import annotations

import threading
import time
import traceback
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from app.gaussians import GaussianArrays
from fixer4d.geometry.camera import Camera

# Publish the model to the viewer every this many steps: a full parameter copy costs about as
# much as a step on small models, so every step would halve training speed.
PUBLISH_EVERY = 10
# ... and at most this often: every published model makes the UI re-upload, re-sort and redraw
# the splats, CPU work that competes with training on a software GL.
PUBLISH_MIN_S = 1.0
# Steps over which the steps-per-second estimate (for the ETA) is averaged.
RATE_WINDOW = 20
# Loss records kept for the plot.
MAX_HISTORY = 20000


class Mailbox:
    """Latest-value handoff between threads."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._value: Any = None
        self._serial = 0

    def put(self, value: Any) -> None:
        with self._lock:
            self._value = value
            self._serial += 1

    def take(self, seen: int) -> tuple[int, Any] | None:
        """(serial, value) if something newer than serial ``seen`` was put, else None."""
        with self._lock:
            if self._serial == seen:
                return None
            return self._serial, self._value


class TrainingSession:
    """Trains in a background thread.

    setup: called once in the thread as ``setup(report)``, returns the ``Trainer`` (e.g. runs
      init, builds the model; slow work stays off the UI thread); ``report(text)`` sets
      ``setup_status`` for the UI. State goes idle -> setup -> running <-> paused -> done (or
      failed, with ``error`` holding the message).
    """

    def __init__(self, setup: Callable[[Callable[[str], None]], Any], publish_every: int = PUBLISH_EVERY,
                 publish_min_s: float = PUBLISH_MIN_S) -> None:
        self._setup = setup
        self.publish_every = int(publish_every)
        self.publish_min_s = float(publish_min_s)
        self.setup_status = ""
        self.setup_started: float | None = None
        self._step_times: list[float] = []
        self.models = Mailbox()
        self.state = "idle"
        self.error: str | None = None
        self.trainer: Any = None
        self.history: list[dict[str, float]] = []
        self._history_lock = threading.Lock()
        self._run = threading.Event()
        self._quit = threading.Event()
        self._thread: threading.Thread | None = None
        self.step_seconds = 0.0
        self.stepping = False  # inside Trainer.step() right now
        # Pause by itself once the trainer has taken this many steps (None: never); the time
        # (perf_counter) at which it did is ``paused_at_time``. "Train to step N", and how the
        # viewer benchmark gives the live trainer turns of exactly as many steps as the plain loop.
        self.pause_at: int | None = None
        self.paused_at_time: float | None = None

    # ---- control (UI thread) ------------------------------------------------------------------
    def start(self) -> None:
        if self._thread is None:
            self._run.set()
            self._thread = threading.Thread(target=self._loop, name="viewer-training", daemon=True)
            self._thread.start()
        else:
            self.resume()

    def pause(self) -> None:
        self._run.clear()
        if self.state == "running":
            self.state = "paused"

    def resume(self) -> None:
        if self.state in ("paused", "running", "setup"):
            self._run.set()
            if self.state == "paused":
                self.state = "running"

    def stop(self, timeout: float = 10.0) -> None:
        self._quit.set()
        self._run.set()
        if self.trainer is not None and hasattr(self.trainer, "stop"):
            self.trainer.stop()
        if self._thread is not None:
            self._thread.join(timeout)

    @property
    def total_steps(self) -> int | None:
        cfg = getattr(self.trainer, "config", None)
        return None if cfg is None else int(getattr(cfg, "iterations", 0)) or None

    @property
    def steps_per_s(self) -> float:
        """Recent training speed (steps per second of step time)."""
        times = self._step_times[-RATE_WINDOW:]
        return 0.0 if not times else len(times) / max(sum(times), 1e-9)

    @property
    def eta_s(self) -> float | None:
        total, rate = self.total_steps, self.steps_per_s
        return None if total is None or rate <= 0 else max(total - self.step, 0) / rate

    def set_stage2(self, **changes: Any) -> bool:
        """Change stage-2 knobs (lambda_gen, refresh_every) of the running trainer; False when it
        is not a stage-2 trainer."""
        st2 = getattr(self.trainer, "stage2", None)
        if st2 is None:
            return False
        for k, v in changes.items():
            setattr(st2, k, v)
        return True

    def losses(self) -> list[dict[str, float]]:
        with self._history_lock:
            return list(self.history)

    @property
    def step(self) -> int:
        return 0 if self.trainer is None else int(self.trainer.step_count)

    # ---- the thread ---------------------------------------------------------------------------
    def _loop(self) -> None:
        try:
            self.state = "setup"
            self.setup_started = time.monotonic()
            self.trainer = self._setup(self._report)
            self.setup_status = "training"
            self.models.put(GaussianArrays.from_model(self.trainer.model))
            published = time.monotonic()
            self.state = "running" if self._run.is_set() else "paused"
            while not self._quit.is_set():
                if not self._run.wait(0.1):
                    continue
                if self._quit.is_set():
                    break
                if self.trainer.done:
                    self.state = "done"
                    break
                self.state = "running"
                self.stepping = True
                tic = time.perf_counter()
                try:
                    rec = self.trainer.step()
                finally:
                    self.stepping = False
                self.step_seconds = time.perf_counter() - tic
                self._step_times.append(self.step_seconds)
                del self._step_times[:-RATE_WINDOW]
                with self._history_lock:
                    self.history.append({k: float(v) for k, v in rec.items() if isinstance(v, (int, float))})
                    del self.history[:-MAX_HISTORY]
                now = time.monotonic()
                if self.trainer.done or (self.trainer.step_count % self.publish_every == 0
                                         and now - published >= self.publish_min_s):
                    self.models.put(GaussianArrays.from_model(self.trainer.model))
                    published = now
                if self.pause_at is not None and self.trainer.step_count >= self.pause_at:
                    self.pause_at = None
                    self.paused_at_time = time.perf_counter()
                    self.pause()
        except Exception as exc:  # shown in the training panel; the UI keeps running
            self.state = "failed"
            self.error = f"{type(exc).__name__}: {exc}"
            traceback.print_exc()

    def _report(self, text: str) -> None:
        self.setup_status = str(text)


def live_stage1_trainer(scene: Any, iterations: int | None, method: str, init_frames: int,
                        report: Callable[[str], None] = lambda text: None) -> Any:
    """Live training through the pipeline's own stage functions (``fixer4d.pipeline.stages``):
    the run defaults of ``fixer4d run`` (stage-1 settings, the 3DGS schedule scaled to the
    iterations, init-point and Gaussian caps, model terms by evidence), ``method`` init clouds of
    about ``init_frames`` evenly spaced frames, and the Trainer ``stages.stage1_trainer`` builds.
    The init is written into a temporary run folder removed before returning.
    ``report(text)`` is called at each setup step. Returns the ``Trainer``."""
    import shutil
    import tempfile
    from pathlib import Path

    from fixer4d.pipeline import stages
    from fixer4d.pipeline.config import resolve
    from fixer4d.pipeline.run_folder import RunFolder

    stride = max(1, scene.num_frames // max(int(init_frames), 1))
    overrides: dict[str, Any] = {"init.method": method, "init_frame_stride": stride}
    if iterations is not None:
        overrides["training.iterations"] = int(iterations)
    config = resolve(overrides=overrides)
    tmp = Path(tempfile.mkdtemp(prefix="fixer4d-view-init-"))
    try:
        ctx = stages.StageContext(run=RunFolder(tmp, config), scene=scene, progress=False)
        report(f"init: {method} point clouds of every {stride}th frame (of {scene.num_frames})")
        init = stages.init_stage(ctx, method)
        report(f"model: init -> Gaussians (cap {config.training.max_gaussians}), model terms {config.model_terms.mode}")
        trainer, _ = stages.stage1_trainer(ctx, init, run_dir=None)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    report(f"trainer: {trainer.total_iterations} steps")
    return trainer


# ---- restoration ------------------------------------------------------------------------------

@dataclass
class QueuedRestore:
    """One (trajectory, frame) restoration as the UI sees it: first the render of its request
    (phase "rendering"), then the ``RestoreJobs`` job."""

    key: str
    trajectory: str
    frame: int
    phase: str = "rendering"
    job: Any = None
    error: str | None = None
    future: Future | None = field(default=None, repr=False)
    cancelled: bool = False

    @property
    def status(self) -> str:
        if self.error is not None:
            return "failed"
        if self.cancelled and self.job is None:
            return "cancelled"
        return self.phase if self.job is None else str(self.job.status)

    @property
    def progress(self) -> float:
        return 0.0 if self.job is None else float(self.job.progress)

    def cancel(self) -> None:
        self.cancelled = True
        if self.future is not None:
            self.future.cancel()
        if self.job is not None:
            self.job.cancel()


class RestoreQueue:
    """Queue restorations: ``build_request()`` (renders, slow) runs on a worker thread, then the
    request goes to ``jobs.submit(request, round, key, meta)``."""

    def __init__(self, jobs: Any, round_index: Callable[[], int], kind: str = "warp") -> None:
        self.jobs = jobs
        self.kind = kind  # the restorer kind new jobs use
        self._retired: list[Any] = []  # earlier jobs objects, still finishing what they took
        self.round_index = round_index
        self.items: list[QueuedRestore] = []
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="viewer-restore-render")

    def queue(self, key: str, trajectory: str, frame: int, build_request: Callable[[], Any],
              meta: dict[str, Any]) -> QueuedRestore:
        item = QueuedRestore(key=key, trajectory=trajectory, frame=frame)

        def work() -> None:
            try:
                if item.cancelled:
                    return
                request = build_request()
                if item.cancelled:
                    return
                item.job = self.jobs.submit(request, self.round_index(), key, meta)
                item.phase = "submitted"
            except Exception as exc:
                item.error = f"{type(exc).__name__}: {exc}"
                traceback.print_exc()

        item.future = self._pool.submit(work)
        self.items.append(item)
        return item

    def set_jobs(self, jobs: Any, kind: str) -> None:
        """New requests go to ``jobs`` (another restorer); queued ones finish where they are."""
        self._retired.append(self.jobs)
        self.jobs, self.kind = jobs, kind

    def wait_all(self, timeout: float = 600.0) -> bool:
        """Block until every queued item finished (tests and scripts). True if all did."""
        deadline = time.monotonic() + timeout
        for item in list(self.items):
            if item.future is not None:
                try:
                    item.future.result(max(deadline - time.monotonic(), 0.0))
                except Exception:
                    return False
            if item.job is not None and not item.job.wait(max(deadline - time.monotonic(), 0.0)):
                return False
        return True

    def shutdown(self) -> None:
        for item in self.items:
            if item.status in ("rendering", "queued"):
                item.cancel()
        self._pool.shutdown(wait=False, cancel_futures=True)
        for jobs in [*self._retired, self.jobs]:
            jobs.shutdown()


def restore_request(model_render: Callable[[Camera, float], dict[str, np.ndarray]], scene: Any,
                    cameras: list[Camera], frame: int, ref_ids: tuple[int, int], trajectory_meta: dict[str, Any]
                    ) -> Any:
    """A ``fixer4d.restore.base.RestoreRequest`` for one trajectory clip at ``frame``.

    model_render(camera, t) -> {"rgb" (H,W,3), "depth" (H,W), "alpha" (H,W)} renders the current
    model; ref_ids are the scene camera indices of the two endpoint (real) views; the other
    train views of that frame go in as extra references. The request carries the clip's
    unobserved-pixel map (``fixer4d.restore.visibility``, default thresholds), as the pipeline's do.
    """
    from fixer4d.restore.base import RestoreRequest
    from fixer4d.restore.visibility import TrainView, unobserved_clip

    t = scene.time(frame)
    clip = [model_render(c, t) for c in cameras]
    refs = [scene.cameras[i] for i in ref_ids]
    ref_renders = [model_render(c, t) for c in refs]
    extra_ids = [i for i in scene.train_ids if i not in ref_ids]
    extra_cams = [scene.cameras[i] for i in extra_ids]
    extra_renders = [model_render(c, t) for c in extra_cams]
    train = [TrainView(c, r["depth"], r["alpha"]) for c, r in zip(refs + extra_cams, ref_renders + extra_renders)]
    unobserved = unobserved_clip(cameras, [c["depth"] for c in clip], [c["alpha"] for c in clip], train)
    return RestoreRequest(
        rgb=np.stack([c["rgb"] for c in clip]), depth=np.stack([c["depth"] for c in clip]),
        alpha=np.stack([c["alpha"] for c in clip]), cameras=list(cameras), time=t, frame=int(frame),
        ref_images=[scene.frame(frame, i) for i in ref_ids], ref_cameras=refs,
        ref_depths=[r["depth"] for r in ref_renders], ref_alphas=[r["alpha"] for r in ref_renders],
        extra_images=[scene.frame(frame, i) for i in extra_ids], extra_cameras=extra_cams,
        extra_depths=[r["depth"] for r in extra_renders], trajectory=dict(trajectory_meta), unobserved=unobserved)
