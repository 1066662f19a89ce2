"""How well each pixel of a novel view is already observed by the train cameras.

Pseudo-supervision is worth having only where the four real views say nothing: a surface point
that a train camera sees from nearly the same direction is already constrained by that camera's
real frames, and a restored pseudo-target there can only repeat them (at best) or contradict them
(a misaligned warp, a hallucination). ``unobserved_weight`` returns, per novel pixel, a weight in
[0, 1]: 1 where the render is a hole or the rendered surface is seen by no train camera (occluded
or outside every frame), 0 where a train camera sees it within ``angle_full_deg`` of the novel
ray, a linear ramp in between.

Everything here uses the MODEL's renders only (depth and alpha at the novel view and at the train
cameras): never a real image and never a held-out camera, so the same weight can mark the region
of a held-out view that the train cameras do not explain, for evaluation.

Rule, per novel pixel p with rendered depth z_p and alpha a_p:
1. hole = ramp(a_p) from 0 at ``hole_alpha_high`` to 1 at ``hole_alpha_low`` (nothing rendered);
2. X = the surface point at p (back-projected at z_p);
3. for each train camera c: X projects inside c's frame, in front of it, and not behind the
   surface c renders there (z_c(X) <= (1 + ``occlusion_rel_tol``) x the 3x3 max of c's rendered
   depth, where c's alpha >= ``alpha_min``): visible_c;
4. angle_c = the angle at X between the rays to the novel camera and to c;
   seen_c = visible_c x ramp(angle_c) (1 up to ``angle_full_deg``, 0 from ``angle_none_deg``);
5. weight = max(hole, 1 - max_c seen_c).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import cv2
import numpy as np

from fixer4d.errors import InputError
from fixer4d.geometry.camera import Camera
from fixer4d.restore.reference_warp import backproject, project, sanitize_depth


@dataclass(frozen=True)
class VisibilityConfig:
    """Thresholds of ``unobserved_weight`` (see the module docstring for the rule).

    alpha_min: a train camera's rendered depth is trusted for the occlusion test where its alpha
      is at least this (the restorers' trusted-depth threshold).
    hole_alpha_low / hole_alpha_high: the novel render is a hole below low, solid above high.
    occlusion_rel_tol: relative depth slack of the occlusion test: the restorers' tolerance.
    angle_full_deg / angle_none_deg: a train camera whose ray meets the novel ray at X within
      angle_full_deg observes X fully; from angle_none_deg on it tells nothing about how X looks
      from the novel view. 25 degrees is about the spacing of a sparse 4-camera rig (Panoptic's
      neighbours are 20-30 degrees apart), so a pseudo-view between two neighbours sees observed
      surfaces as observed; beyond 60 degrees appearance and foreshortening differ too much.
    """

    alpha_min: float = 0.5
    hole_alpha_low: float = 0.2
    hole_alpha_high: float = 0.8
    occlusion_rel_tol: float = 0.03
    angle_full_deg: float = 25.0
    angle_none_deg: float = 60.0

    def __post_init__(self) -> None:
        if not 0.0 <= self.hole_alpha_low < self.hole_alpha_high <= 1.0:
            raise InputError(f"visibility: need 0 <= hole_alpha_low < hole_alpha_high <= 1, got "
                             f"{self.hole_alpha_low}, {self.hole_alpha_high}")
        if not 0.0 <= self.angle_full_deg < self.angle_none_deg <= 180.0:
            raise InputError(f"visibility: need 0 <= angle_full_deg < angle_none_deg <= 180, got "
                             f"{self.angle_full_deg}, {self.angle_none_deg}")
        if not (self.occlusion_rel_tol > 0 and 0.0 <= self.alpha_min <= 1.0):
            raise InputError("visibility: occlusion_rel_tol must be > 0 and alpha_min in [0, 1]")


@dataclass
class TrainView:
    """A train camera with the model's depth and alpha rendered there, (H, W) each."""

    camera: Camera
    depth: np.ndarray
    alpha: np.ndarray


def _ramp(x: np.ndarray, zero_at: float, one_at: float) -> np.ndarray:
    """Linear 0..1 ramp: 0 at ``zero_at``, 1 at ``one_at`` (either order), clipped."""
    return np.clip((x - zero_at) / (one_at - zero_at), 0.0, 1.0)


def hole_weight(alpha: np.ndarray, config: VisibilityConfig | None = None) -> np.ndarray:
    """(...) float32 in [0, 1] of an alpha map (...): 1 where the render holds nothing (alpha at or
    below ``hole_alpha_low``), 0 where it is solid (at or above ``hole_alpha_high``), linear between."""
    cfg = config or VisibilityConfig()
    a = np.clip(np.nan_to_num(np.asarray(alpha, np.float32), nan=0.0), 0.0, 1.0)
    return _ramp(a, cfg.hole_alpha_high, cfg.hole_alpha_low).astype(np.float32)


def _max3x3(depth: np.ndarray) -> np.ndarray:
    return cv2.dilate(depth.astype(np.float32), np.ones((3, 3), np.uint8))


def unobserved_weight(camera: Camera, depth: np.ndarray, alpha: np.ndarray, train: Sequence[TrainView],
                      config: VisibilityConfig | None = None) -> np.ndarray:
    """(H, W) float32 in [0, 1]: how unobserved each pixel of ``camera``'s render is (1 = no train
    camera explains it; see the module docstring). depth, alpha: (H, W) the model's render at
    ``camera``. train: the train cameras with the model's renders there."""
    cfg = config or VisibilityConfig()
    H, W = camera.height, camera.width
    depth = np.asarray(depth)
    alpha = np.asarray(alpha, np.float32)
    if depth.shape != (H, W) or alpha.shape != (H, W):
        raise InputError(f"unobserved_weight: depth {depth.shape} and alpha {alpha.shape} must be the camera's "
                         f"({H}, {W})")
    z = sanitize_depth(depth)
    hole = hole_weight(alpha, cfg)
    solid = (z > 0) & (alpha >= cfg.hole_alpha_low)
    seen = np.zeros((H, W), np.float64)
    if solid.any() and len(train):
        X = backproject(camera, z)[solid]  # (N, 3) surface points
        to_novel = camera.center[None, :] - X
        to_novel /= np.maximum(np.linalg.norm(to_novel, axis=1, keepdims=True), 1e-12)
        best = np.zeros(len(X), np.float64)
        for view in train:
            c = view.camera
            d = sanitize_depth(view.depth)
            d = np.where(np.asarray(view.alpha) >= cfg.alpha_min, d, 0.0)
            uv, zc = project(c, X)
            inside = np.isfinite(uv).all(axis=1) & (zc > 0)
            ui = np.floor(np.nan_to_num(uv[:, 0], nan=-1.0)).astype(np.int64)
            vi = np.floor(np.nan_to_num(uv[:, 1], nan=-1.0)).astype(np.int64)
            inside &= (ui >= 0) & (ui < c.width) & (vi >= 0) & (vi < c.height)
            limit = np.zeros(len(X), np.float64)
            dmax = _max3x3(d)
            limit[inside] = dmax[vi[inside], ui[inside]]
            # a train pixel without trusted depth (limit 0) does not vouch for X: the model renders
            # nothing solid there, so that camera's real frame never shaped X
            visible = inside & (limit > 0) & (zc <= limit * (1.0 + cfg.occlusion_rel_tol))
            to_c = c.center[None, :] - X
            to_c /= np.maximum(np.linalg.norm(to_c, axis=1, keepdims=True), 1e-12)
            angle = np.degrees(np.arccos(np.clip(np.sum(to_novel * to_c, axis=1), -1.0, 1.0)))
            best = np.maximum(best, visible * _ramp(angle, cfg.angle_none_deg, cfg.angle_full_deg))
        seen[solid] = best
    return np.maximum(hole, 1.0 - seen).astype(np.float32)


def unobserved_clip(cameras: Sequence[Camera], depths: np.ndarray, alphas: np.ndarray, train: Sequence[TrainView],
                    config: VisibilityConfig | None = None) -> np.ndarray:
    """(F, H, W) float32: ``unobserved_weight`` of every frame of a rendered clip."""
    return np.stack([unobserved_weight(c, d, a, train, config) for c, d, a in zip(cameras, depths, alphas)])


def unobserved_fraction(weight: np.ndarray) -> float:
    """Mean of an unobserved weight map or clip: the share of pixels left to pseudo-supervision."""
    w = np.asarray(weight, np.float64)
    return float(w.mean()) if w.size else 0.0


__all__ = ["VisibilityConfig", "TrainView", "hole_weight", "unobserved_weight", "unobserved_clip", "unobserved_fraction"]
