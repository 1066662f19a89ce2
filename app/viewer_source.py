"""What the viewer is given: the source it shows (``ViewerSource``) and the services it calls
(``ViewerServices``: opening sources, torch renders, restoration jobs, videos).

The viewer builds neither models nor restorers itself: ``app.main`` (the composition root)
passes ``app.sources.app_services()``, tests may pass fakes. So nothing under the UI imports
the model's internals, and nothing imports back into ``app.main``.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

from fixer4d.errors import InputError

# fn(camera, t) -> {"rgb" (H,W,3), "depth" (H,W), "alpha" (H,W)} float32 arrays of the shown Gaussians
GaussiansRenderFn = Callable[[Any, float], dict]


@dataclass
class ViewerSource:
    """What the viewer shows and drives.

    scene: the multi-view video (cameras, real frames), or None for a bare model.
    run_dir: the run folder (edits are saved there), or None.
    training: a live ``app.session.TrainingSession`` whose mailbox delivers models, or None.
    cache: a ``fixer4d.restore.cache.RestoreCache`` (the compare panel reads it), or None.
    restore: an ``app.session.RestoreQueue`` to queue restorations, or None.
    render_backend: the torch rasterizer backend for compare/restore renders.
    model_path: the model file shown, or None (live training).
    segments: a segmented run's ``app.segments.SegmentTimeline`` (the shown Gaussians follow the
      segment that owns the current frame), or None.
    notice: what the user should know about how the source was resolved (shown when it opens),
      e.g. a bundled scene name that is also a folder here.
    background: the RGB in [0, 1] the run trains and restores over where no Gaussian lies
      (``training.background`` resolved for its scene, e.g. the train views' mean colour), or None
      for a bare model. Restoration jobs and Compare render over it, like the pseudo-targets.
    """

    scene: Any = None
    run_dir: Path | None = None
    label: str = ""
    training: Any = None
    cache: Any = None
    restore: Any = None
    render_backend: str = "auto"
    model_path: Path | None = None
    segments: Any = None
    notice: str = ""
    background: tuple[float, float, float] | None = None


def _missing(what: str) -> Callable[..., Any]:
    def fail(*args: Any, **kwargs: Any) -> Any:
        raise InputError(f"this viewer was started without {what}; start it with fixer4d-view")
    return fail


@dataclass
class ViewerServices:
    """The functions the viewer calls for work outside the UI.

    open_source(text) -> (ViewerSource, GaussianArrays or None, session folder): File > Open.
    initial_state(source, gaussians) -> AppState: a fresh session for a source.
    render(key, gaussians, segments, segment, background, backend) -> GaussiansRenderFn: torch renders
      of the shown Gaussians (``key`` changes whenever they do; the model is built once per key).
    make_jobs(kind, cache, run_dir) -> RestoreJobs: a restorer of ``kind`` for new jobs.
    render_video(model_fn, cameras, times, out, fps, progress, should_stop) -> Path: a video of
      the render along cameras/times (``app.video_job``).
    config_dir: the user's viewer folder (recent files, first-launch hint).
    """

    open_source: Callable[[str], tuple] = _missing("a source opener")
    initial_state: Callable[[ViewerSource, Any], Any] = _missing("a state factory")
    render: Callable[..., GaussiansRenderFn] = _missing("a renderer")
    render_twin: Callable[..., GaussiansRenderFn] = _missing("a twin renderer")
    make_jobs: Callable[[str, Any, Path | None], Any] = _missing("a restorer factory")
    render_video: Callable[..., Path] = _missing("a video writer")
    config_dir: Path = Path.home() / ".config" / "fixer4d" / "view"
