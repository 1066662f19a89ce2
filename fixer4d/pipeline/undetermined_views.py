"""Pseudo-views where the model is undetermined: extra restored clips beyond
the pair trajectories and arcs, on paths to the cameras of an orbit pool whose views the model
leaves most undetermined (``trajectories.undetermined_views`` = k; 0 = off).

    weight = unobserved_weight_fn(model, scene.train_cameras, visibility)   # or any WeightFn
    clips = undetermined_trajectories(scene, tc, weight, times)             # [(Trajectory, ids)]

A ``WeightFn`` maps a camera and a time to an (H, W) per-pixel weight in [0, 1] (1 = the model
is undetermined there); a candidate's score is its mean over pixels and the scoring times. The
default is the train cameras' ``unobserved`` weight (``restore.visibility``) from the model's own
renders; a twin field's render disagreement is another such function. Nothing here reads an
image: the pool and the paths come from the train cameras' poses, the scores from renders.
"""
from __future__ import annotations

from typing import Callable, Sequence

import numpy as np

from fixer4d.geometry.camera import Camera
from fixer4d.geometry.trajectory import Trajectory
from fixer4d.geometry.view_candidates import approach_path, orbit_candidates, pick_separated, rig_frame
from fixer4d.render.views import render_views
from fixer4d.restore.visibility import TrainView, VisibilityConfig, unobserved_weight

# ``weight(camera, t) -> (H, W)`` in [0, 1] at ``camera`` (any size) and time t in [0, 1)
WeightFn = Callable[[Camera, float], np.ndarray]

# Candidates and train views are scored at this fraction of their image size: a view's score is a
# mean over its pixels, which a quarter-size render gives to well under a percent, at 1/16 the
# render and visibility cost of the pool (about 50 cameras at each scoring time).
SCORE_SCALE = 0.25
# Azimuths of the pool, every 30 degrees: finer than the picks' separation (25 degrees by
# default) would add cameras the separation then forbids side by side.
POOL_AZIMUTHS = 12
# Scoring times per round: the first, middle and last restored frames (a moving subject changes
# what is unobserved over the clip; three times see its start, middle and end).
SCORE_TIMES = 3


def unobserved_weight_fn(model, train_cameras: Sequence[Camera], visibility: VisibilityConfig,
                         backend: str = "auto") -> WeightFn:
    """The train cameras' unobserved weight of ``model`` at a camera (``restore.visibility``),
    rendered at ``SCORE_SCALE``; the train cameras' renders are made once per time."""
    train = [c.scaled(SCORE_SCALE) for c in train_cameras]
    memo: dict[float, list[TrainView]] = {}

    def weight(camera: Camera, t: float) -> np.ndarray:
        if t not in memo:
            _, depth, alpha = render_views(model, train, t, backend)
            memo[t] = [TrainView(c, d, a) for c, d, a in zip(train, depth, alpha)]
        cam = camera.scaled(SCORE_SCALE)
        _, depth, alpha = render_views(model, [cam], t, backend)
        return unobserved_weight(cam, depth[0], alpha[0], memo[t], visibility)

    return weight


def score_views(cameras: Sequence[Camera], times: Sequence[float], weight: WeightFn) -> np.ndarray:
    """(N,) mean of ``weight`` over each camera's pixels and ``times``: the share of its view the
    model leaves undetermined."""
    return np.array([np.mean([float(np.mean(weight(c, t))) for t in times]) for c in cameras], np.float64)


def scoring_times(scene, frames: Sequence[int]) -> list[float]:
    """The clip times the candidates are scored at: ``SCORE_TIMES`` of the restored ``frames``,
    spread evenly (every one when fewer)."""
    picks = np.unique(np.linspace(0, len(frames) - 1, min(SCORE_TIMES, len(frames))).round().astype(int))
    return [scene.time(frames[i]) for i in picks]


def undetermined_trajectories(scene, tc, weight: WeightFn, times: Sequence[float]
                              ) -> list[tuple[Trajectory, tuple[int, int]]]:
    """The paths to the ``tc.undetermined_views`` best-scored pool cameras (``TrajectoryConfig``:
    pool elevations, radii, separation), with their references as scene camera ids, like
    ``pipeline.restoration.scene_trajectories_for``. [] when the option is off."""
    if tc.undetermined_views <= 0:
        return []
    train = scene.train_cameras
    e = tc.undetermined_elevation_deg
    pool = orbit_candidates(train, azimuths=POOL_AZIMUTHS, elevations_deg=sorted({-e, 0.0, e}),
                            radii=sorted({1.0, tc.undetermined_radius}))
    if not pool:
        return []
    center = rig_frame(train).center
    directions = np.stack([(c.center - center) / np.linalg.norm(c.center - center) for c in pool])
    picks = pick_separated(directions, score_views(pool, times, weight), tc.undetermined_views,
                           tc.undetermined_separation_deg)
    out = []
    for k, i in enumerate(picks):
        tr = approach_path(train, pool[i], tc.frames, k)
        out.append((tr, (scene.train_ids[tr.pair[0]], scene.train_ids[tr.pair[1]])))
    return out
