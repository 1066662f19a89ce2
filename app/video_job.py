"""A video of the current trajectory rendered in the background: progress, cancel, the result.

The frames are torch renders of the shown Gaussians (edits included) along the trajectory's
cameras, at the clip times of the trajectory's frames starting at the current frame; the file
is written by the injected ``services.render_video`` (``fixer4d.render.video`` in the app).
"""
from __future__ import annotations

import threading
import traceback
from pathlib import Path
from typing import Any, Callable


class VideoJob:
    """One video render on a worker thread. ``progress`` 0..1, ``result`` the path written,
    ``error`` one line when it failed, ``cancel()`` stops it between frames."""

    def __init__(self, write: Callable[..., Path], render_fn: Any, cameras: list, times: list[float], out: Path,
                 fps: float) -> None:
        self.out = Path(out)
        self.progress = 0.0
        self.result: Path | None = None
        self.error: str | None = None
        self.detail: str | None = None  # the traceback of a failure (for the log)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, args=(write, render_fn, cameras, times, fps),
                                        name="video-render", daemon=True)
        self._thread.start()

    @property
    def running(self) -> bool:
        return self._thread.is_alive()

    @property
    def cancelled(self) -> bool:
        return self._stop.is_set()

    def cancel(self) -> None:
        self._stop.set()

    def wait(self, timeout: float | None = None) -> None:
        self._thread.join(timeout)

    def _set_progress(self, value: float) -> None:
        self.progress = float(min(max(value, 0.0), 1.0))

    def _run(self, write, render_fn, cameras, times, fps) -> None:
        try:
            self.result = Path(write(render_fn, cameras, times, self.out, fps=fps, progress=self._set_progress,
                                     should_stop=self._stop.is_set))
            if not self._stop.is_set():
                self.progress = 1.0
        except Exception as exc:  # shown in the panel; the app goes on
            if self._stop.is_set():  # cancelled: the writer removed its partial output
                return
            self.error = f"{type(exc).__name__}: {exc}"
            self.detail = traceback.format_exc()


def trajectory_times(frame: int, n_cameras: int, num_frames: int) -> list[float]:
    """Clip times of a trajectory's frames: the current ``frame`` and the ones after it (one clip
    frame per trajectory frame, wrapping at the end), t = f / num_frames."""
    n = max(int(num_frames), 1)
    return [((frame + k) % n) / n for k in range(n_cameras)]
