"""The model a training starts from: spacetime Gaussians from an init, and the scene extent.

    model = model_from_clouds(clouds, scene, TrainingConfig())          # per-frame point clouds
    model, decision = model_from_init(init, scene, TrainingConfig())    # clouds or a DecomposedInit
    extent = scene_extent(scene.train_cameras, model.means)           # the length sizes scale with
"""
from __future__ import annotations

import logging
from typing import Any, Sequence

import numpy as np
import torch

from fixer4d.errors import InputError
from fixer4d.geometry.camera import Camera, rig_extent
from fixer4d.geometry.subsample import subsample
from fixer4d.model.terms import ModelTermsConfig, TermsDecision
from fixer4d.model.initial_scales import knn_scales
from fixer4d.model.spacetime import ModelConfig, SpacetimeGaussians
from fixer4d.scene.base import MultiViewVideo
from fixer4d.train.config import TrainingConfig

log = logging.getLogger("fixer4d.train")

# 3DGS's scene radius is 1.1 x the largest camera distance from the rig centre.
EXTENT_MARGIN = 1.1
# Floor of the extent (a single point seen by coincident cameras).
_DEGENERATE_RIG = 1e-6
# Percentile of point distances from the cloud median used as the cloud's radius (robust to
# the stray far points MVS and SfM leave).
_CLOUD_RADIUS_PERCENTILE = 90.0
# Fewer points than this cannot give a 3-NN scale; such an init is topped up with random points.
MIN_INIT_POINTS = 4
# Random points used when an init is degenerate (empty or < MIN_INIT_POINTS points): enough to
# cover a small scene coarsely; densification refines from there.
FALLBACK_POINTS = 2000
# Colour of fallback points: mid grey, the least-biased guess.
FALLBACK_COLOR = 0.5


def model_from_clouds(clouds: Sequence[Any], scene: MultiViewVideo, config: TrainingConfig,
                      model_config: ModelConfig | None = None) -> SpacetimeGaussians:
    """Spacetime Gaussians from per-frame clouds (fixer4d.init.cloud.FrameCloud: frame, time,
    points (N,3), colors (N,3)).

    Each point becomes a Gaussian with time centre = its frame's time, isotropic scale = the RMS
    distance to its 3 nearest neighbours *within its frame* (points of different frames
    coincide on static content and would give degenerate scales), opacity ``config.init_opacity``.
    At most ``config.init_max_points`` points are kept (``config.init_subsample``: a seeded
    uniform draw, a seeded stratified one or an even spread, frame by frame;
    fixer4d.geometry.subsample). An empty or nearly empty init (< MIN_INIT_POINTS points) is topped up with FALLBACK_POINTS random points
    inside the scene bounds (logged); without known bounds it raises InputError.
    """
    pts_l, col_l, t_l, fid_l = [], [], [], []
    for i, c in enumerate(clouds):
        p = np.asarray(c.points, dtype=np.float64).reshape(-1, 3)
        ok = np.all(np.isfinite(p), axis=1)
        pts_l.append(p[ok])
        col_l.append(np.clip(np.asarray(c.colors, dtype=np.float64).reshape(-1, 3)[ok], 0.0, 1.0))
        t_l.append(np.full(int(ok.sum()), float(c.time)))
        fid_l.append(np.full(int(ok.sum()), i))
    points = np.concatenate(pts_l) if pts_l else np.zeros((0, 3))
    colors = np.concatenate(col_l) if col_l else np.zeros((0, 3))
    times = np.concatenate(t_l) if t_l else np.zeros(0)
    group = np.concatenate(fid_l) if fid_l else np.zeros(0, np.int64)
    rng = np.random.default_rng(config.seed)

    if points.shape[0] > config.init_max_points:
        keep = subsample(points, config.init_max_points, config.init_subsample, rng, groups=group)
        points, colors, times, group = points[keep], colors[keep], times[keep], group[keep]

    scales = np.zeros(points.shape[0])
    lone = np.zeros(points.shape[0], bool)
    for g in np.unique(group):
        sel = group == g
        if sel.sum() >= 2:
            scales[sel] = knn_scales(points[sel])
        else:
            lone |= sel
    if lone.any():  # a frame's only point has no neighbour in its frame: measure it against every frame's
        scales[lone] = knn_scales(points)[lone]
    if points.shape[0] < MIN_INIT_POINTS:
        fb_points, fb_times = _fallback_points(scene, rng)
        log.warning("init has %d point(s) (< %d): adding %d random points inside the scene bounds; "
                    "the reconstruction will rely on densification", points.shape[0], MIN_INIT_POINTS, len(fb_points))
        points = np.concatenate([points, fb_points])
        colors = np.concatenate([colors, np.full_like(fb_points, FALLBACK_COLOR)])
        times = np.concatenate([times, fb_times])
        # every scale is recomputed over the whole set: a lone point has no neighbour in its frame
        scales = knn_scales(points)
    return SpacetimeGaussians.from_points(points, colors, times, model_config,
                                          opacity=config.init_opacity, scales=scales)


def _fallback_points(scene: MultiViewVideo, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(FALLBACK_POINTS, 3) uniform points inside the scene's bounding box and their (FALLBACK_POINTS,)
    times, each a random frame's time."""
    bounds = scene.bounds()
    if bounds is None:
        raise InputError(f"{scene.name}: the init point clouds are empty and the scene has no known bounds to "
                         "place random points in; re-run `fixer4d init` with the other method (--init mvs|sparse) "
                         "or check the cameras")
    lo = np.asarray(bounds.bbox_min, np.float64)
    hi = np.asarray(bounds.bbox_max, np.float64)
    pts = lo + rng.random((FALLBACK_POINTS, 3)) * (hi - lo)
    frames = rng.integers(0, scene.num_frames, FALLBACK_POINTS)
    return pts, frames / float(scene.num_frames)


def model_from_init(init: Any, scene: MultiViewVideo, config: TrainingConfig,
                    terms: ModelTermsConfig | None = None) -> tuple[SpacetimeGaussians, TermsDecision | None]:
    """The model of an init and the model-terms decision behind it.

    init: a DecomposedInit (fixer4d.init.decompose) -> terms decided by evidence
    (fixer4d.model.terms.decide_terms; ``terms`` picks auto | all | static and forced
    switches), or per-frame clouds -> ``model_from_clouds`` with the default terms on every
    Gaussian (decision None; e.g. the sparse baseline). A decomposed init with fewer than
    MIN_INIT_POINTS points takes the per-frame path too (random points, decision None).
    """
    from fixer4d.model.terms import decide_terms, model_from_decomposed

    if isinstance(init, (list, tuple)):
        return model_from_clouds(init, scene, config), None
    if init.num_static + init.num_dynamic < MIN_INIT_POINTS:
        # nothing to decide the terms from (e.g. a textureless capture): the per-frame path, whose
        # degenerate init is topped up with random points like any other
        log.warning("the decomposed init has %d point(s): training from random points with every term on",
                    init.num_static + init.num_dynamic)
        return model_from_clouds(init.frame_clouds(), scene, config), None
    decision = decide_terms(init, terms)
    model = model_from_decomposed(init, decision, opacity=config.init_opacity, max_points=config.init_max_points,
                                  seed=config.seed, subsample_method=config.init_subsample)
    return model, decision


def scene_extent(cameras: Sequence[Camera], means: torch.Tensor) -> float:
    """The length every size threshold and the position learning rate scale with:
    EXTENT_MARGIN x the larger of the rig radius (3DGS's camera extent) and the init cloud's
    radius. The cloud term matters for narrow, forward-facing rigs (cameras 1 m apart filming a
    scene 4 m away), where the rig alone would call every background Gaussian "too large"."""
    r = rig_extent(list(cameras))
    pts = means.detach().cpu().double().numpy()
    if pts.shape[0]:
        r = max(r, float(np.percentile(np.linalg.norm(pts - np.median(pts, 0), axis=1), _CLOUD_RADIUS_PERCENTILE)))
    return EXTENT_MARGIN * max(r, _DEGENERATE_RIG)
