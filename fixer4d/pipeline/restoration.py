"""Everything between a model and its restored pseudo-targets: renders, restore requests, the
stage-2 cache refresh and the "restoration" evaluation rows. Restorers never render: the request
built here carries every render they need (docs/design.md §11).

Clips are named by scene camera ids everywhere (``RestoreCache.key(frame, cam_i, cam_j, arc, view)``).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np

from fixer4d.geometry.camera import Camera
from fixer4d.pipeline.config import RunConfig, TrajectoryConfig
from fixer4d.render.views import model_render_fn, render_views
from fixer4d.restore.visibility import VisibilityConfig

# The learned restorer's folder inside a run (weights, training pairs, validation.json).
RESTORER_DIR = "restorer"


@dataclass
class TwinWeight:
    """Stage 1's twin field (co_fields; RUN/model_stage1_twin.ply) and ``co_fields.weight``: how
    its disagreement with the rendered model (``restore.undetermined``) enters a request's
    ``unobserved`` weight (``restore.undetermined.combined_weight``)."""

    model: Any
    mode: str


def twin_weight_for(config: RunConfig, run_dir: str | Path) -> TwinWeight | None:
    """The run's TwinWeight, None unless co_fields is on with a weight other than "visibility"."""
    cf = config.co_fields
    if not cf.enabled or cf.weight == "visibility":
        return None
    from fixer4d.model.io import load_ply
    from fixer4d.train.co_fields import TWIN_NAME

    return TwinWeight(load_ply(Path(run_dir) / TWIN_NAME), cf.weight)


def make_request(model, scene, cameras: list[Camera], frame: int, ref_ids: tuple[int, int], *,
                 backend: str = "auto", trajectory: dict[str, Any] | None = None,
                 visibility: VisibilityConfig | None = None, twin: TwinWeight | None = None,
                 background: tuple[float, float, float] | None = None):
    """Render a clip and everything the restorer needs at the references (restorers never render).

    background: the RGB the renders show where nothing covers a pixel (the run's
    ``training.background``, resolved; None: black), the colour the model trains over.

    visibility: when given, the request carries ``unobserved`` (F, H, W): how unobserved each
    clip pixel is by the scene's train cameras (``restore.visibility``, from these renders).
    twin: with ``visibility``, ``unobserved`` is instead that weight combined with the
    disagreement of the twin's renders of the clip (``TwinWeight``)."""
    from fixer4d.restore.base import RestoreRequest
    from fixer4d.restore.visibility import TrainView, unobserved_clip

    t = scene.time(frame)
    ref_cams = [scene.cameras[i] for i in ref_ids]
    extra_ids = [i for i in scene.train_ids if i not in ref_ids]
    extra_cams = [scene.cameras[i] for i in extra_ids]
    # one call, so a clip's endpoints (= the reference cameras) are rendered once
    rgb_all, depth_all, alpha_all = render_views(model, list(cameras) + ref_cams + extra_cams, t, backend, background)
    n, m = len(cameras), len(cameras) + len(ref_cams)
    rgb, depth, alpha = rgb_all[:n], depth_all[:n], alpha_all[:n]
    ref_depth, ref_alpha, extra_depth = depth_all[n:m], alpha_all[n:m], depth_all[m:]
    unobserved = None
    if visibility is not None:
        train = [TrainView(c, d, a) for c, d, a in zip(ref_cams + extra_cams, depth_all[n:], alpha_all[n:])]
        unobserved = unobserved_clip(cameras, depth, alpha, train, visibility)
        if twin is not None:
            from fixer4d.restore.undetermined import combined_weight, undetermined_map

            twin_rgb, _, twin_alpha = render_views(twin.model, list(cameras), t, backend, background)
            undetermined = np.stack([undetermined_map(*x) for x in zip(rgb, twin_rgb, alpha, twin_alpha)])
            unobserved = combined_weight(unobserved, undetermined, twin.mode)
    return RestoreRequest(
        rgb=rgb, depth=depth, alpha=alpha, cameras=list(cameras), time=t, frame=frame,
        ref_images=[scene.frame(frame, i) for i in ref_ids], ref_cameras=ref_cams,
        ref_depths=list(ref_depth), ref_alphas=list(ref_alpha),
        extra_images=[scene.frame(frame, i) for i in extra_ids] or None, extra_cameras=extra_cams or None,
        extra_depths=list(extra_depth) or None, trajectory=trajectory or {}, unobserved=unobserved)


def run_restorer(config: RunConfig, run_dir: str | Path | None = None):
    """The restorer of a run: ``restore.build_restorer`` of its config, a learned one with the
    weights ``restorer_stage`` trained into RUN/restorer."""
    from fixer4d.restore.factory import build_restorer

    return build_restorer(config.restorer, None if run_dir is None else Path(run_dir) / RESTORER_DIR)


def scene_trajectories_for(scene, tc: TrajectoryConfig):
    """The 6 pair trajectories (+ arcs) of the scene's train cameras; pairs are mapped from
    train-list indices to scene camera indices."""
    from fixer4d.geometry.trajectory import scene_trajectories

    trajs = scene_trajectories(scene.train_cameras, tc.frames, amplitude=tc.amplitude, arcs=tc.arcs, seed=tc.seed)
    return [(tr, (scene.train_ids[tr.pair[0]], scene.train_ids[tr.pair[1]])) for tr in trajs]


# Restore jobs handed to the executor at once: enough to keep a few workers busy, few enough that
# the rendered requests of one batch (frames x H x W x 5 float32 each) stay small in memory.
RESTORE_BATCH = 8


def _restore_job(job):
    """(restorer, request) -> result; a top-level function so a Ray worker can run it."""
    restorer, request = job
    return restorer.restore(request)


def make_refresh_callback(run_dir: str | Path, scene, config: RunConfig, *, progress: bool = True,
                          backend: str = "auto", executor=None, restorer=None,
                          twin: TwinWeight | None = None) -> Callable[[Any, int], None]:
    """The stage-2 cache refresh: render every trajectory (the pair paths and arcs, and with
    ``trajectories.undetermined_views`` the paths to the views the current model leaves most
    undetermined, ``pipeline.undetermined_views``) at every restored timestamp with the
    current model, restore the clips (on ``executor``: local by default, Ray when configured),
    write them to RUN/cache/round_<r> (with ``stage2.pseudo_target = "gated"``, each restored frame
    blended into its render by confidence x unobserved weight first). Complete entries of a round are reused (a resumed run does
    not redo them). restorer: the run's configured one when None (a diagnostic may pass another,
    e.g. benchmarks/stage2_ceiling.py's ground-truth oracle). twin: the requests' ``TwinWeight``
    (None: the visibility weight alone)."""
    from fixer4d.pipeline.executors import LocalExecutor
    from fixer4d.pipeline.keys import stage2_key
    from fixer4d.restore.cache import RestoreCache
    from fixer4d.train.background import resolve_background

    # entries written under other settings (restorer, trajectories, stage-1 model) are set aside
    cache = RestoreCache(Path(run_dir) / "cache", fingerprint=stage2_key(config))
    cache.clean_temporary()  # leftovers of a killed write; complete entries are reused below
    restorer = restorer if restorer is not None else run_restorer(config, run_dir)
    executor = executor or LocalExecutor()
    trajectories = scene_trajectories_for(scene, config.trajectories)
    frames = list(range(0, scene.num_frames, max(1, config.trajectories.time_stride)))
    gated = config.stage2.pseudo_target == "gated"
    background = resolve_background(config.training.background, scene)

    def refresh(model, round_index: int) -> None:
        from tqdm.auto import tqdm

        from fixer4d.pipeline.undetermined_views import scoring_times, undetermined_trajectories, unobserved_weight_fn

        clips = list(trajectories)
        if config.trajectories.undetermined_views:  # picked anew each round, where the current model is undetermined
            weight = unobserved_weight_fn(model, scene.train_cameras, config.stage2.visibility, backend)
            clips += undetermined_trajectories(scene, config.trajectories, weight, scoring_times(scene, frames))
        todo = [(f, tr, ids) for f in frames for tr, ids in clips
                if not cache.has(round_index, clip_key(cache, f, tr, ids))]
        bar = tqdm(total=len(todo), desc=f"restore round {round_index}", unit="clip", disable=not progress,
                   leave=False)
        for start in range(0, len(todo), RESTORE_BATCH):
            batch = todo[start:start + RESTORE_BATCH]
            requests = [make_request(model, scene, tr.cameras, f, ids, backend=backend,
                                     trajectory=clip_meta(tr, ids), visibility=config.stage2.visibility,
                                     twin=twin, background=background)
                        for f, tr, ids in batch]
            results = executor.map(_restore_job, [(restorer, req) for req in requests])
            if gated:  # the pseudo-target: restored where unobserved and trusted, the fallback elsewhere
                results = [gate_restoration(req, res, config.stage2.visibility, config.stage2.fill_unobserved,
                                            config.stage2.restore_holes)
                           for req, res in zip(requests, results)]
            for (f, tr, ids), req, res in zip(batch, requests, results):
                cache.write(round_index, clip_key(cache, f, tr, ids), req, res,
                            {"restorer": restorer.name, "restorer_settings": restorer.settings(),
                             "restorer_kind": config.restorer.kind, "model_gaussians": int(model.num_gaussians),
                             "pseudo_target": config.stage2.pseudo_target})
            bar.update(len(batch))
        bar.close()

    return refresh


def clip_key(cache, frame: int, trajectory, ids: tuple[int, int]) -> str:
    """The cache entry of ``trajectory``'s clip at ``frame`` (references ``ids``, scene camera ids)."""
    return cache.key(frame, ids[0], ids[1], trajectory.arc_index, trajectory.view_index)


def clip_meta(trajectory, ids: tuple[int, int]) -> dict[str, Any]:
    """The request's trajectory metadata (kept in the cache entry); ``view_index`` only on the
    path to an undetermined view, so the pair paths' entries read as before."""
    meta = {"name": trajectory.name, "pair": list(ids), "amplitude": float(trajectory.amplitude),
            "arc_index": trajectory.arc_index}
    if trajectory.view_index is not None:
        meta["view_index"] = int(trajectory.view_index)
    return meta


def gate_restoration(request, result, visibility: VisibilityConfig, fill: bool, restore_holes: bool = True):
    """The restored clip where the restorer may act, a fallback elsewhere: one gate for the
    Restoration rows and stage 2's gated pseudo-targets (``restore.base.blend_with_render`` with
    the request's unobserved map as weight).

    With ``fill`` (``eval.fill_unobserved`` for the rows, ``stage2.fill_unobserved`` for the
    targets) the fallback is the render with its unobserved pixels, holes included, filled from
    the observed ones around them at or behind their depth (``restore.unobserved_fill.fill_unobserved``
    with the render's depth and alpha), and the restorer acts in
    proportion to its confidence x unobserved; the result's confidence is the larger of that
    weight and the fill's (where the target departs from the render). Without it the fallback is
    the render as it is, which holds only the background colour in a hole; with ``restore_holes``
    (``stage2.restore_holes``) a hole takes the restored frame whatever the confidence
    (``restore.visibility.hole_weight``), without it a hole is an unobserved pixel like any other.
    """
    from fixer4d.restore.base import RestoreResult, blend_with_render
    from fixer4d.restore.unobserved_fill import UNKNOWN_ABOVE, fill_unobserved
    from fixer4d.restore.visibility import hole_weight

    if fill and request.unobserved is not None:
        filled = fill_unobserved(request.rgb, request.unobserved, request.depth, request.alpha)
        gated = blend_with_render(filled, result, request.unobserved)
        # the returned confidence says where the target departs from the render: the restorer's
        # share, and the fill's wherever it replaces the render
        u = np.clip(np.nan_to_num(request.unobserved, nan=0.0), 0.0, 1.0)
        departs = np.maximum(gated.confidence, np.where(u > UNKNOWN_ABOVE, u, 0.0)).astype(np.float32)
        return RestoreResult(rgb=gated.rgb, confidence=departs,
                             frame_confidence=departs.reshape(len(departs), -1).mean(axis=1))
    holes = hole_weight(request.alpha, visibility) if restore_holes else None
    return blend_with_render(request.rgb, result, request.unobserved, holes)


def clip_frame(request, result, index: int):
    """Frame ``index`` of a restored clip as a one-frame (request, result): what a gate needs when
    only that frame is used (the clip's fill is solved per frame)."""
    import dataclasses

    from fixer4d.restore.base import RestoreResult

    one = slice(index, index + 1)
    request = dataclasses.replace(
        request, rgb=request.rgb[one], depth=request.depth[one], alpha=request.alpha[one],
        cameras=request.cameras[one], unobserved=None if request.unobserved is None else request.unobserved[one])
    return request, RestoreResult(rgb=result.rgb[one], confidence=result.confidence[one],
                                  frame_confidence=result.frame_confidence[one])


def clip_through(scene, camera: Camera) -> tuple[list[Camera], tuple[int, int]]:
    """The Restoration rows' clip through ``camera``: the two train cameras nearest to it are the
    references, the clip is (midpoint ref_a..camera, camera, midpoint camera..ref_b). Returns
    (the three cameras, the two reference train ids)."""
    from fixer4d.geometry.trajectory import interpolate_pair, same_pose

    def midpoint(c0: Camera, c1: Camera) -> Camera:
        # a held-out camera may sit exactly where a train camera is (a duplicated pose): no path
        # runs between them, and the midpoint is that pose itself
        return c1 if same_pose(c0, c1) else interpolate_pair(c0, c1, np.array([0.5]), 0.0)[0]

    d = [np.linalg.norm(scene.cameras[i].center - camera.center) for i in scene.train_ids]
    order = np.argsort(d)
    ids = (scene.train_ids[order[0]], scene.train_ids[order[1]])
    a, b = scene.cameras[ids[0]], scene.cameras[ids[1]]
    return [midpoint(a, camera), camera, midpoint(camera, b)], ids


def restoration_render_fn(model, scene, restorer, backend: str = "auto", visibility: VisibilityConfig | None = None,
                          fill: bool = True, twin: TwinWeight | None = None,
                          background: tuple[float, float, float] | None = None
                          ) -> Callable[[Camera, float], np.ndarray]:
    """A render function for evaluation whose images are *restored* renders: the restored middle
    frame of ``clip_through`` the held-out camera (the "restoration" rows of the paper's Table 2).
    visibility: when given, the frame is ``gate_restoration``'s (the restored frame where the train
    cameras leave the pixel unobserved, by the restorer's confidence; the unobserved fill there
    with ``fill``, else the render, whose holes take the restored frame); None: the restorer's
    output as it is (the paper's rows). twin: the gate's weight takes the twin field's
    disagreement in (``make_request``). background: the renders' (``make_request``).
    """

    def fn(camera: Camera, t: float) -> np.ndarray:
        frame = int(round(t * scene.num_frames))
        cams, ids = clip_through(scene, camera)
        req = make_request(model, scene, cams, frame, ids, backend=backend,
                           trajectory={"name": f"through-{camera.name}", "pair": list(ids), "amplitude": 0.0},
                           visibility=visibility, twin=twin, background=background)
        result = restorer.restore(req)
        if visibility is None:
            return result.rgb[1]
        return gate_restoration(*clip_frame(req, result, 1), visibility, fill).rgb[0]

    return fn


def blur_render_fn(model, sigma_px: float, backend: str = "auto",
                   background: tuple[float, float, float] | None = None) -> Callable[[Camera, float], np.ndarray]:
    """``fn(camera, t) -> (H,W,3)``: the model's render blurred by a Gaussian of ``sigma_px``
    pixels (the "Blur" baseline beside the restoration rows: a restoration gain means something
    only against the render itself and against a plain low-pass of it)."""
    import cv2

    plain = model_render_fn(model, backend, background)

    def fn(camera: Camera, t: float) -> np.ndarray:
        return cv2.GaussianBlur(plain(camera, t), (0, 0), sigmaX=float(sigma_px), sigmaY=float(sigma_px))

    return fn


class UnobservedMasks:
    """``masks(camera_index, frame) -> (H, W) bool``: the pixels of a (held-out) camera that no
    train camera explains, from ``model``'s renders at that camera and at the train cameras
    (``restore.visibility``; weight > 0.5). Reads no image: safe for held-out cameras. Masks are
    memoized, so every report row of one model scores the same region. The model is copied: stage
    2 trains the stage-1 model in place, and a resumed run computes the masks only after it."""

    def __init__(self, model, scene, visibility: VisibilityConfig, backend: str = "auto") -> None:
        import copy

        self.model = copy.deepcopy(model)
        self.scene = scene
        self.visibility = visibility
        self.backend = backend
        self._memo: dict[tuple[int, int], np.ndarray] = {}

    def __call__(self, cam_idx: int, frame: int) -> np.ndarray:
        from fixer4d.restore.visibility import TrainView, unobserved_weight

        key = (int(cam_idx), int(frame))
        if key not in self._memo:
            scene = self.scene
            cam = scene.cameras[cam_idx]
            train = scene.train_cameras
            _, depth, alpha = render_views(self.model, [cam] + list(train), scene.time(frame), self.backend)
            views = [TrainView(c, d, a) for c, d, a in zip(train, depth[1:], alpha[1:])]
            self._memo[key] = unobserved_weight(cam, depth[0], alpha[0], views, self.visibility) > 0.5
        return self._memo[key]


def pseudo_view_summary(cache_dir: str | Path) -> dict[str, Any] | None:
    """What stage 2 supervised, per cache round: clips, and the share of their pixels left to the
    pseudo-loss (``unobserved_fraction``: mean, min, max over clips). None without a cache."""
    from fixer4d.restore.cache import RestoreCache

    cache = RestoreCache(cache_dir)
    rounds = {}
    for r in cache.rounds():
        fractions = [e.meta.get("scores", {}).get("unobserved_fraction") for e in cache.entries(r)]
        known = [float(f) for f in fractions if f is not None]
        rounds[str(r)] = {"clips": len(fractions),
                          "unobserved_fraction": None if not known else
                          {"mean": float(np.mean(known)), "min": float(np.min(known)), "max": float(np.max(known))}}
    return rounds or None
