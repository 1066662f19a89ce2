"""Opening what the viewer shows and building the work it delegates: run folders, model files,
scenes trained live, restorers for new jobs, torch renders of the shown Gaussians and of a
model's twin field, videos.

``app_services()`` bundles these as the ``ViewerServices`` that ``app.main`` hands the viewer;
this module never imports the viewer, its panels or ``app.main``.
"""
from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Any, Callable

import numpy as np

from app.camera_control import ViewCamera, rig_up
from app.session import RestoreQueue, TrainingSession, live_stage1_trainer
from app.state import AppState
from app.viewer_source import GaussiansRenderFn, ViewerServices, ViewerSource
from fixer4d.errors import Fixer4DError, InputError

# First view of a scene: from the rig, pulled back by this factor of its distance to the scene
# centre and lifted by this fraction of the scene radius.
START_PULLBACK = 1.15
START_LIFT = 0.05
# Live training from a scene: the default init method (dense MVS, the paper's) and how many
# evenly spaced frames get an init cloud. Plane-sweep MVS costs ~25 s per frame of the demo on
# 2 CPU cores, so a live preview starts from a few keyframes; the temporal opacity of the
# Gaussians spans the gaps and training fills in the rest.
LIVE_INIT_METHOD = "mvs"
LIVE_INIT_FRAMES = 3


def config_dir() -> Path:
    """The user's viewer folder: $XDG_CONFIG_HOME/fixer4d/view (default ~/.config)."""
    base = os.environ.get("XDG_CONFIG_HOME") or str(Path.home() / ".config")
    return Path(base) / "fixer4d" / "view"


def _slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]+", "_", text).strip("_")[-80:] or "default"


def open_source(source: str, *, scale: float = 1.0, iterations: int | None = None, init: str = LIVE_INIT_METHOD,
                init_frames: int = LIVE_INIT_FRAMES) -> tuple[ViewerSource, Any, Path]:
    """Resolve a source the user named. Returns (ViewerSource, initial GaussianArrays or None,
    folder for the viewer's session files). A folder of videos (a capture) or any scene
    ``load_scene`` opens is trained live; a bare bundled name ("demo") is the bundled scene even
    where a folder of that name exists (``ViewerSource.notice`` then says so)."""
    from fixer4d.scene.synthetic import is_builtin_name

    from app.files import is_model_file, is_run_folder

    path = Path(source).expanduser()
    if is_builtin_name(source):  # as everywhere in fixer4d: a bare name is the bundled scene
        src, g, session_dir = open_scene(source, scale, iterations, init, init_frames)
        if path.exists():
            src.notice = (f"opened the built-in scene '{source}'; a folder of that name is here too: open it as "
                          f"./{source}")
        return src, g, session_dir
    if is_run_folder(path):
        return open_run(path.resolve())
    if path.is_file() and is_model_file(path):
        return open_model(path.resolve())
    return open_scene(source, scale, iterations, init, init_frames)


def open_scene(source: str, scale: float, iterations: int | None, init: str,
               init_frames: int) -> tuple[ViewerSource, Any, Path]:
    """A scene ``load_scene`` opens (bundled name, spec .json, scene or capture folder), to be
    trained live; its session lives under the user's config folder."""
    from fixer4d.scene import load_scene
    from fixer4d.scene.synthetic import is_builtin_name

    path = Path(source).expanduser()
    scene = load_scene(source, scale=scale)
    training = TrainingSession(lambda report: live_stage1_trainer(scene, iterations, init, init_frames, report))
    session_dir = config_dir() / _slug(source if is_builtin_name(source) or not path.exists() else str(path.resolve()))
    cache, restore = make_restore(session_dir / "cache")
    src = ViewerSource(scene=scene, label=f"{scene.name} (live training)", training=training, cache=cache,
                       restore=restore, background=run_background(None, scene))
    return src, None, session_dir


def open_model(path: Path) -> tuple[ViewerSource, Any, Path]:
    """A model file (.ply / .npz): inside a run folder, that run with this model version; else
    the model alone (no scene), its session under the user's config folder."""
    from app.files import is_run_folder
    from app.gaussians import GaussianArrays
    from fixer4d.model.io import load_model

    if is_run_folder(path.parent):
        return open_run(path.parent, model=path)
    g = GaussianArrays.from_model(load_model(path))
    src = ViewerSource(label=str(path), model_path=path)
    return src, g, config_dir() / _slug(str(path))


def open_run(run: Path, model: Path | None = None) -> tuple[ViewerSource, Any, Path]:
    """A run folder: its scene, a model version (``model``, else the one the session remembers,
    else model_final / model_stage1; a segmented run without a top-level model: its segments'
    models on the clip's timeline, ``app.segments``), its restoration cache and a restorer for
    new jobs."""
    from app.files import choose_model, model_versions, remembered_version
    from app.gaussians import GaussianArrays
    from app.segments import SegmentTimeline, segment_models
    from fixer4d.model.io import load_model
    from fixer4d.pipeline.run_folder import load_scene_for, read_run_config

    config = read_run_config(run)  # read only: the viewer never rewrites config.json
    scene = load_scene_for(config)
    background = run_background(config, scene)
    if model is None and not model_versions(run) and segment_models(run):
        timeline = SegmentTimeline.load(run, scene.num_frames)
        cache, restore = make_restore(run / "cache", run)
        src = ViewerSource(scene=scene, run_dir=run, label=f"{run} ({len(timeline.ranges)} segments)", cache=cache,
                           restore=restore, segments=timeline, background=background)
        return src, timeline.arrays[timeline.segment_of(0.0)], run / "viewer"
    model_path = model if model is not None else choose_model(run, remembered_version(run / "viewer" / "session.json"))
    g = GaussianArrays.from_model(load_model(model_path))
    cache, restore = make_restore(run / "cache", run)
    src = ViewerSource(scene=scene, run_dir=run, label=str(model_path), cache=cache, restore=restore,
                       model_path=model_path, background=background)
    return src, g, run / "viewer"


def run_background(config: Any, scene: Any) -> tuple[float, float, float]:
    """The RGB a run of ``config`` (None: the default config, as live training uses) trains and
    restores ``scene`` over: its ``training.background`` resolved from the scene's train views."""
    from fixer4d.pipeline.config import resolve
    from fixer4d.train.background import resolve_background

    return resolve_background((config if config is not None else resolve()).training.background, scene)


def make_restore(cache_dir: Path, run_dir: Path | None = None) -> tuple[Any, RestoreQueue]:
    """The on-disk cache and a queue feeding the restorer: the run's own kind when its
    config.json names one that can be built here (e.g. learned with RUN/restorer weights), else
    the geometric warp restorer (CPU, no weights)."""
    from fixer4d.restore.cache import RestoreCache

    cache = RestoreCache(cache_dir)
    kind = "warp"
    if run_dir is not None:
        from fixer4d.pipeline.run_folder import read_run_config

        try:
            kind = read_run_config(run_dir).restorer.kind
        except InputError:
            kind = "warp"
    try:
        jobs = make_jobs(kind, cache, run_dir)
    except Fixer4DError:  # e.g. no learned weights yet: start with the warp restorer
        kind, jobs = "warp", make_jobs("warp", cache, run_dir)
    return cache, RestoreQueue(jobs, lambda: cache.latest_round() or 0, kind=kind)


def make_jobs(kind: str, cache: Any, run_dir: Path | None) -> Any:
    """``RestoreJobs`` around the restorer of ``kind`` (fixer4d.restore.build_restorer;
    the learned restorer's weights come from RUN/restorer)."""
    from fixer4d.restore import RestoreConfig, build_restorer
    from fixer4d.restore.jobs import RestoreJobs

    restorer = build_restorer(RestoreConfig(kind=kind), None if run_dir is None else run_dir / "restorer")
    return RestoreJobs(restorer, cache)


def initial_state(src: ViewerSource, gaussians: Any) -> AppState:
    """State for a fresh session: the scene's timeline, a view from the first train camera's
    side at the rig, the default trajectories. The rig's frusta and paths start hidden for a
    finished run and for live training (the model first, the rig on demand)."""
    from app.trajectories import default_specs

    st = AppState()
    scene = src.scene
    if scene is not None:
        st.num_frames, st.fps = scene.num_frames, float(scene.fps)
        cams = scene.train_cameras or scene.cameras
        from fixer4d.geometry.rig import rig_focus

        bounds = scene.bounds()
        center = rig_focus(cams, None if bounds is None else
                           (np.asarray(bounds.bbox_min, float) + np.asarray(bounds.bbox_max, float)) / 2.0)
        radius = float(np.max(np.linalg.norm(np.stack([c.center for c in scene.cameras]) - center, axis=1)))
        st.view = ViewCamera(up=rig_up(scene.cameras), fov_y=cams[0].fov_y)
        rig = np.mean([c.center for c in cams], axis=0)
        # from behind the rig, a little above it: the rig's frusta and the scene both in view
        eye = center + START_PULLBACK * (rig - center) + START_LIFT * radius * st.view.up
        st.view.look_from(eye, center, scene_radius=radius)
        if len(scene.train_ids) >= 2:
            st.trajectories = default_specs(scene.train_cameras, max(2, min(scene.num_frames, 16)),
                                            camera_ids=scene.train_ids)
            st.selected_trajectory = 0
        if src.run_dir is not None or src.training is not None:
            st.show_frusta = st.show_trajectories = False
    elif gaussians is not None and gaussians.n:  # a bare model: orbit its bulk from outside
        lo, hi = np.percentile(gaussians.means, [5, 95], axis=0)
        center, radius = (lo + hi) / 2.0, float(np.linalg.norm(hi - lo) / 2.0) or 1.0
        st.view.look_from(center - 2.5 * radius * st.view.forward(), center, scene_radius=radius)
    if src.model_path is not None:
        st.model_version = src.model_path.name
    st.set_gaussians(gaussians, base=src.model_path)
    return st


class TorchRenders:
    """Torch renders of the Gaussians the viewer shows (compare, restore, videos): the model is
    converted once per ``key`` (the viewer's edit version and shown segment)."""

    def __init__(self) -> None:
        self._key: Any = None
        self._model: Any = None

    def model(self, key: Any, gaussians: Any, segments: Any, segment: int | None) -> Any:
        """A ``SpacetimeGaussians`` of ``gaussians``, or for a segmented run the stitched
        ``SegmentedModel`` of every segment (the shown one, ``segment``, with its edits)."""
        if self._key != key or self._model is None:
            if segments is not None:
                arrays = [gaussians if k == segment and gaussians is not None else g
                          for k, g in enumerate(segments.arrays)]
                self._model = segments.stitched([g.to_model() for g in arrays])
            else:
                self._model = None if gaussians is None else gaussians.to_model()
            self._key = key
        return self._model

    def __call__(self, key: Any, gaussians: Any, segments: Any, segment: int | None,
                 background: tuple[float, float, float], backend: str) -> GaussiansRenderFn:
        """``fn(camera, t) -> {"rgb", "depth", "alpha"}`` with the torch rasterizer at clip time t
        (a segmented run: the segment that owns t, at its local time), through ``model_renders``."""
        model = self.model(key, gaussians, segments, segment)
        if model is None:
            raise InputError("no model loaded: nothing to render")
        return model_renders(model, background, backend)


class TwinRenders:
    """Torch renders of the model files the undetermined map compares (``app.files.twin_pair``:
    a co_fields twin, or a run's two stage-1 fields); each file is loaded once while the map's
    files stay the same."""

    def __init__(self) -> None:
        self._models: dict[Path, Any] = {}

    def __call__(self, path: Path, background: tuple[float, float, float], backend: str) -> GaussiansRenderFn:
        """``fn(camera, t) -> {"rgb", "depth", "alpha"}`` of the model in ``path`` at clip time t."""
        from fixer4d.model.io import load_model

        path = Path(path)
        if path not in self._models:
            if len(self._models) >= 2:  # a map compares two files at most: another run's files
                self._models.clear()
            self._models[path] = load_model(path)
        return model_renders(self._models[path], background, backend)


def model_renders(model: Any, background: tuple[float, float, float], backend: str) -> GaussiansRenderFn:
    """``fn(camera, t) -> {"rgb" (H, W, 3), "depth" (H, W), "alpha" (H, W)}`` float32 renders of
    ``model`` over ``background`` with the torch rasterizer, through
    ``fixer4d.render.views.render_views``."""
    from fixer4d.render.views import render_views

    background = tuple(background)

    def fn(camera: Any, t: float) -> dict[str, np.ndarray]:
        rgb, depth, alpha = render_views(model, [camera], t, backend, background)
        return {"rgb": rgb[0], "depth": depth[0], "alpha": alpha[0]}
    return fn


def render_video(render_fn: GaussiansRenderFn, cameras: list, times: list[float], out: Path, *, fps: float = 30.0,
                 progress: Callable[[float], None] | None = None,
                 should_stop: Callable[[], bool] | None = None) -> Path:
    """A video of ``render_fn`` along ``cameras`` at clip ``times`` written to ``out``, through
    ``fixer4d.render.video.render_video`` (its render_fn hook: the viewer's renders include
    its edits and segments)."""
    from fixer4d.render.video import render_video as library_render_video

    def hook(camera, t: float) -> np.ndarray:  # the library's render_fn(camera, t) -> (H, W, 3) float RGB
        return render_fn(camera, t)["rgb"]

    def frames_done(done: int, total: int) -> None:  # the library counts frames, the job a fraction
        if progress is not None:
            progress(done / max(total, 1))

    return library_render_video(None, cameras, times, out, fps=fps, render_fn=hook, progress=frames_done,
                                should_stop=should_stop)


def app_services(**overrides: Any) -> ViewerServices:
    """The services of the desktop app (``overrides``: replace some, e.g. in tests)."""
    services = ViewerServices(open_source=open_source, initial_state=initial_state, render=TorchRenders(),
                              render_twin=TwinRenders(), make_jobs=make_jobs, render_video=render_video,
                              config_dir=config_dir())
    for name, value in overrides.items():
        setattr(services, name, value)
    return services
