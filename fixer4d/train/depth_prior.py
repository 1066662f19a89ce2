"""Depth prior: the dense init's points hold stage 1's rendered depth on the train views.

With four cameras a Gaussian can explain a train view's colour from a wrong depth: a faint,
wall-coloured Gaussian floating in front of the wall looks right from the train cameras and
fogs every far view. The multi-view-stereo init already measured where the surfaces are (points
that several train views agree on), so stage 1 can be told: at each train pixel where the init
has a visible point, the render's expected depth (``RenderOutput.depth``, sum_i w_i z_i / alpha)
should be that point's depth.

    target z(v, f): the init's points at frame f z-buffered into train camera v (``point_depth``)
    L_depth = mean over pixels with a target of min(|d - z| / z, RELATIVE_CLIP)
    stage 1's loss per view: L_STG + weight * L_depth

Targets per (train view, frame): a decomposed init's static points at every frame, less the
pixels of that view's moving-content mask (a moving person is not in the static cloud and
occludes it), plus the frame's own moving points where the frame is an init frame; a per-frame
init (clouds at its frames only) gives targets at its frames. Only the train cameras' own init
enters: no held-out image, nothing a held-out camera saw.

``weight = 0`` and ``novel_weight = 0`` (the defaults: it lost on validation cameras,
docs/decisions/depth-prior.md) switch it off: no target is built and every trained digit stays as
it was.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np
import torch

from fixer4d.errors import InputError
from fixer4d.geometry.camera import Camera

# Relative depth errors are clipped here, where their gradient stops: a point seen through a hole
# in a nearer surface, or a stray depth of the fusion, is 50 % or more off and must not pull the
# model, while the fog this prior removes sits 10-40 % in front of its surface (Panoptic's stage-1
# models over black: 7-23 % of train pixels render > 10 % nearer than the init's points,
# benchmarks/results/depth_gap_background_panoptic.json).
RELATIVE_CLIP = 0.5
# Depths are compared relative to the target; this floor keeps the division finite for a point
# on the camera's near plane.
_DEPTH_FLOOR = 1e-6


@dataclass
class DepthPriorConfig:
    """``training.depth_prior``: the init's points as a depth target of stage 1 (module docstring).

    weight: weight of L_depth beside each train view's L_STG (0 = none, the default).
    tolerance: a pixel's nearest point is dropped as seen through a hole when it lies more than
      this fraction behind the nearest point within ``window`` pixels: a sparse cloud's far
      surface shows between the points of a near one.
    window: side (pixels, odd) of that neighbourhood.
    novel_weight: weight of L_depth at one novel camera around the rig (``NovelDepthViews``),
      rendered at an init frame and held to the init's points there (0 = train views only).
    novel_every: a novel camera every this many steps.
    """

    weight: float = 0.0
    tolerance: float = 0.05
    window: int = 5
    novel_weight: float = 0.0
    novel_every: int = 1

    def __post_init__(self) -> None:
        if not self.weight >= 0.0:
            raise InputError(f"depth_prior.weight must be >= 0 (0 = off), got {self.weight}")
        if not self.tolerance >= 0.0:
            raise InputError(f"depth_prior.tolerance must be >= 0, got {self.tolerance}")
        if not self.novel_weight >= 0.0:
            raise InputError(f"depth_prior.novel_weight must be >= 0 (0 = off), got {self.novel_weight}")
        if self.novel_every < 1:
            raise InputError(f"depth_prior.novel_every must be >= 1, got {self.novel_every}")
        if self.window < 1 or self.window % 2 == 0:
            raise InputError(f"depth_prior.window must be an odd number of pixels >= 1, got {self.window}")

    @property
    def enabled(self) -> bool:
        return self.weight > 0.0 or self.novel_weight > 0.0


def point_depth(points: np.ndarray, camera: Camera, tolerance: float, window: int) -> np.ndarray:
    """(H, W) float32 z-depth of the nearest of ``points`` (N, 3) in each pixel of ``camera``, 0
    where no point lands or where the nearest one lies more than ``tolerance`` (fraction) behind
    the nearest point within the ``window`` x ``window`` neighbourhood (seen through a hole)."""
    from scipy.ndimage import minimum_filter

    h, w = camera.height, camera.width
    out = np.zeros((h, w), np.float32)
    if len(points) == 0:
        return out
    uv, z = camera.project(np.asarray(points, np.float64))
    ok = np.isfinite(uv).all(axis=1) & (z > 0)
    u = np.floor(uv[ok, 0]).astype(np.int64)
    v = np.floor(uv[ok, 1]).astype(np.int64)
    z = z[ok]
    inside = (u >= 0) & (u < w) & (v >= 0) & (v < h)
    nearest = np.full((h, w), np.inf)
    np.minimum.at(nearest, (v[inside], u[inside]), z[inside])
    around = minimum_filter(nearest, size=window, mode="nearest")
    keep = np.isfinite(nearest) & (nearest <= around * (1.0 + tolerance))
    out[keep] = nearest[keep]
    return out


def depth_loss(depth: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """L_depth of a rendered depth (H, W) (or a batch (B, H, W)) against ``target`` of the same
    shape (0 = no target): the mean over the pixels with a target of the relative error, clipped
    at RELATIVE_CLIP; 0 when no pixel has a target. Differentiable w.r.t. ``depth``."""
    valid = target > 0
    rel = (depth - target).abs() / target.clamp(min=_DEPTH_FLOOR)
    rel = torch.where(valid, rel.clamp(max=RELATIVE_CLIP), torch.zeros_like(rel))
    return rel.sum() / valid.sum().clamp(min=1)


class DepthTargets:
    """The depth targets of stage 1's train views, built lazily per (view, frame) and kept.

    init: a DecomposedInit (static points at every frame, moving points at their frames) or a
      sequence of FrameCloud (points at their frames only).
    cameras: the train cameras, in the trainer's view order.
    moving: ``moving(view, frame) -> (H, W) bool`` moving-content mask of a train view (the static
      cloud's targets are dropped there).
    """

    def __init__(self, init, cameras: Sequence[Camera], config: DepthPriorConfig,
                 moving: Callable[[int, int], np.ndarray], device: torch.device | str = "cpu") -> None:
        from fixer4d.init.decompose import DecomposedInit

        self.cameras = list(cameras)
        self.config = config
        self.moving = moving
        self.device = torch.device(device)
        if isinstance(init, DecomposedInit):
            self.static = np.asarray(init.static_points, np.float32)
            self.frame_points = {int(f): np.asarray(init.dyn_points[init.dyn_frames == f], np.float32)
                                 for f in init.frames.tolist()}
        else:
            self.static = None
            self.frame_points = {int(c.frame): np.asarray(c.points, np.float32) for c in init}
        self._static_maps: dict[int, np.ndarray] = {}
        self._maps: dict[tuple[int, int], torch.Tensor | None] = {}

    def _depth(self, points: np.ndarray, view: int) -> np.ndarray:
        return point_depth(points, self.cameras[view], self.config.tolerance, self.config.window)

    def _grown(self, mask: np.ndarray) -> np.ndarray:
        """``mask`` grown by half the window: a mask's edge misses a moving silhouette's rim."""
        from scipy.ndimage import maximum_filter

        mask = np.asarray(mask, bool)
        return maximum_filter(mask, size=self.config.window) if self.config.window > 1 else mask

    def target(self, view: int, frame: int) -> torch.Tensor | None:
        """(H, W) float32 target depths of train view ``view`` (index into the trainer's train
        views) at ``frame``, 0 = none; None when the view has no target at that frame."""
        key = (int(view), int(frame))
        if key not in self._maps:
            self._maps[key] = self._build(*key)
        return self._maps[key]

    def _build(self, view: int, frame: int) -> torch.Tensor | None:
        if self.static is None:
            if frame not in self.frame_points:
                return None
            z = self._depth(self.frame_points[frame], view)
        else:
            if view not in self._static_maps:
                self._static_maps[view] = self._depth(self.static, view)
            z = self._static_maps[view].copy()
            if frame in self.frame_points:
                # the frame's moving points are measured at this frame: they replace the mask
                z = self._depth(np.concatenate([self.static, self.frame_points[frame]]), view)
            else:
                z[self._grown(self.moving(view, frame))] = 0.0
        if not (z > 0).any():
            return None
        return torch.from_numpy(z).to(self.device)



# The novel cameras' pool: the orbit of the undetermined views' candidates (every 30 degrees of
# azimuth, at the rig's elevation and 20 degrees above and below it, at the train cameras' mean
# distance): views from around the scene, away from every train camera.
NOVEL_AZIMUTHS = 12
NOVEL_ELEVATIONS_DEG = (-20.0, 0.0, 20.0)


class NovelDepthViews:
    """Depth targets at novel cameras: the init's points at its own frames, z-buffered into cameras
    on an orbit around the rig (``geometry.view_candidates.orbit_candidates``). A far view sees
    the fog in front of a surface that the train views see edge-on or not at all; where the init
    has a visible point, the render's depth there is held to it like a train view's.

    init: a DecomposedInit (static plus the frame's moving points at each init frame) or frame
    clouds. train_cameras: the rig (only their poses and intrinsics enter). ``draw(rng)`` ->
    (camera, frame, (H, W) target) of a random pool camera and init frame, or None without one.
    """

    def __init__(self, init, train_cameras: Sequence[Camera], config: DepthPriorConfig,
                 device: torch.device | str = "cpu") -> None:
        from fixer4d.geometry.view_candidates import orbit_candidates
        from fixer4d.init.decompose import DecomposedInit

        self.config = config
        self.device = torch.device(device)
        clouds = init.frame_clouds() if isinstance(init, DecomposedInit) else init
        self.frame_points = {int(c.frame): np.asarray(c.points, np.float32) for c in clouds}
        self.frames = sorted(self.frame_points)
        self.cameras = (orbit_candidates(list(train_cameras), azimuths=NOVEL_AZIMUTHS,
                                         elevations_deg=NOVEL_ELEVATIONS_DEG, radii=(1.0,))
                        if len(train_cameras) >= 2 else [])
        self._maps: dict[tuple[int, int], torch.Tensor | None] = {}

    def draw(self, rng: np.random.Generator) -> tuple[Camera, int, torch.Tensor] | None:
        if not self.cameras or not self.frames:
            return None
        c, f = int(rng.integers(len(self.cameras))), self.frames[int(rng.integers(len(self.frames)))]
        if (c, f) not in self._maps:
            z = point_depth(self.frame_points[f], self.cameras[c], self.config.tolerance, self.config.window)
            self._maps[(c, f)] = torch.from_numpy(z).to(self.device) if (z > 0).any() else None
        target = self._maps[(c, f)]
        return None if target is None else (self.cameras[c], f, target)


__all__ = ["DepthPriorConfig", "DepthTargets", "NovelDepthViews", "RELATIVE_CLIP", "depth_loss", "point_depth"]
