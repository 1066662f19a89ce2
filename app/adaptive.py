"""Adaptive resolution and level of detail for the 3D view: render less while the view changes,
everything at full size when it rests, and nothing when nothing changed.

On a software GL (Mesa llvmpipe) a splat frame costs per pixel and per splat (triangle setup
runs on one thread: ~3 us a splat, so 30k splats cost ~100 ms even at 1/4 of the pixels). While
the camera moves or time plays the view draws a "work fraction" q <= 1 of the full frame: a
scale s ~ sqrt(q) per side (upscaled by the display) and, with level of detail on, the fraction q
of the splats (``app.gl.lod``: a fixed importance-weighted subset, each kept splat enlarged to
cover for the dropped ones). q is chosen so the estimated cost (full-size cost x q) fits the draw
budget; the full-size cost is re-estimated from every frame as draw_ms / q, which makes the
choice a feedback loop that settles at the budget whatever the split between pixel and splat
costs. The first frame with an unchanged view re-renders everything at full size ("refine");
after that the last image is shown as is.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

# Draw budget per frame while moving (ms), when nothing better is known: with the panels' own
# ~20-40 ms on llvmpipe this keeps orbiting at >= 10 frames per second (the bar). The
# viewer replaces it every frame by what is left of FRAME_TARGET_MS after the panels.
MOVING_BUDGET_MS = 45.0
# The whole frame's target while moving (ms): 10 frames per second, the bar.
FRAME_TARGET_MS = 100.0
# Bounds of the draw budget the viewer derives from FRAME_TARGET_MS: below 15 ms the moving
# image degrades to a few hundred blobs for little gain (the panels then dominate anyway); above
# 60 ms a fast GL gains nothing (it draws everything well within it).
MIN_BUDGET_MS = 15.0
MAX_BUDGET_MS = 60.0
# Smallest scale per side: below 1/8 the splats blur into a few blocks and orbiting loses the
# scene's shape (looked at on the demo), so a view slower than the budget at 1/8 is drawn at 1/8
# anyway (level of detail then takes the rest). Level of detail keeps the splats' fragment count
# (the kept ones are enlarged), so on a loaded machine the pixels are what is left to cut: at 1/4
# the demo's 2000-splat frame cost 35-40 ms at load ~11, two thirds of it fragments.
MIN_SCALE = 0.125
# Fewest splats a level-of-detail frame draws: below ~2000 enlarged splats the demo's scene
# loses its objects' outlines (looked at on the demo's surfaces); on llvmpipe 2000 splats cost
# ~6-10 ms.
LOD_MIN_SPLATS = 2000
# Weight of the newest measurement in the running estimate of the full-size draw cost; the cost
# changes with what is in view, so it follows within a few frames.
COST_SMOOTHING = 0.5
# Scales are rounded to this step so the render targets are not re-allocated every frame.
SCALE_STEP = 1.0 / 16.0


# Frames the view must rest (unchanged) before the full-size refine: a drag whose mouse skips a
# frame must not pay a full-size render in the middle of the motion.
REFINE_AFTER_FRAMES = 2


@dataclass
class AdaptiveResolution:
    """Decides, per frame, whether and at what scale the 3D view is rendered.

    ``plan(key)`` -> scale in (0, 1] to render at, or None to keep the last image; ``key`` is
    anything comparable that changes whenever the image would (camera, time, model, modes, size).
    With level of detail on (``lod``, and ``splats`` set to the model's Gaussian count)
    ``fraction`` is the fraction of the splats the planned render draws (1 otherwise).
    ``done(scale, draw_ms, complete, fraction)`` reports the render (complete: drawn with the
    exact depth order for the view, so a full-size complete image of every splat is final until
    the key changes).
    """

    enabled: bool = True
    budget_ms: float = MOVING_BUDGET_MS
    full_cost_ms: float | None = None  # running estimate of the full-size draw cost
    last_key: object = None
    final: bool = False  # the last image is full size, complete and for last_key
    moving: bool = False
    scale: float = 1.0  # scale of the last render
    rest: int = 0  # frames since the key last changed
    lod: bool = True  # level of detail while moving (fewer splats), besides the smaller scale
    splats: int = 0  # Gaussians in the model (level of detail keeps at least LOD_MIN_SPLATS)
    fraction: float = 1.0  # fraction of the splats the last planned render draws

    def plan(self, key: object) -> float | None:
        if key != self.last_key:
            self.last_key, self.rest, self.final, self.moving = key, 0, False, True
            return self._moving_plan()
        self.rest += 1
        if self.final:
            self.moving = False
            return None
        if (self.scale < 1.0 or self.fraction < 1.0) and self.rest < REFINE_AFTER_FRAMES:
            return None  # maybe still moving: keep the quick image a moment
        self.moving = False
        self.fraction = 1.0
        return 1.0

    def _moving_plan(self) -> float:
        self.fraction = 1.0
        if not self.enabled or self.full_cost_ms is None:
            return 1.0
        q = self.budget_ms / max(self.full_cost_ms, 1e-3)  # work fraction of a full-size frame
        if self.lod and self.splats > 0 and q < 1.0:
            self.fraction = min(1.0, max(q, LOD_MIN_SPLATS / self.splats))
        s = math.sqrt(q)
        if s >= 1.0:
            return 1.0
        return max(MIN_SCALE, math.floor(s / SCALE_STEP) * SCALE_STEP)

    def work(self, scale: float, fraction: float = 1.0) -> float:
        """The estimated cost of a render at ``scale`` drawing ``fraction`` of the splats, as a
        fraction of a scale-1 render of all of them (the pixels' share ~ scale^2; with fewer
        splats the smaller of the two, which the feedback through ``done`` corrects)."""
        area = scale * scale
        return max(min(area, fraction) if fraction < 1.0 else area, 1e-6)

    def done(self, scale: float, draw_ms: float, complete: bool, fraction: float = 1.0) -> None:
        full = draw_ms / self.work(scale, fraction)
        self.full_cost_ms = full if self.full_cost_ms is None else \
            COST_SMOOTHING * full + (1.0 - COST_SMOOTHING) * self.full_cost_ms
        self.scale = scale
        self.fraction = fraction
        self.final = scale >= 1.0 and complete and fraction >= 1.0

    def invalidate(self) -> None:
        """Render again next frame although the key did not change."""
        self.final = False
        self.last_key = object()
