"""Adaptive resolution for the 3D view: render smaller while the view changes, full size when
it rests, and not at all when nothing changed.

On a software GL (Mesa llvmpipe) the splat draw costs about proportionally to the rendered
pixels, so while the camera moves or time plays the view is rendered at a scale s <= 1 per side
(cost ~ s^2), chosen from the measured full-size cost so the draw fits a frame budget, and
upscaled by the display (linear filtering). The first frame with an unchanged view re-renders
at full size ("refine"); after that the last image is shown as is.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

# Draw budget per frame while moving (ms): with the panels' own ~20-40 ms on llvmpipe this keeps
# orbiting at >= 10 frames per second (the bar).
MOVING_BUDGET_MS = 45.0
# Smallest scale per side: below 1/4 the splats blur into a few blocks and orbiting loses the
# scene's shape, so a view slower than the budget at 1/4 is drawn at 1/4 anyway.
MIN_SCALE = 0.25
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
    ``done(scale, draw_ms, complete)`` reports the render (complete: drawn with the exact depth
    order for the view, so a full-size complete image is final until the key changes).
    """

    enabled: bool = True
    budget_ms: float = MOVING_BUDGET_MS
    full_cost_ms: float | None = None  # running estimate of the full-size draw cost
    last_key: object = None
    final: bool = False  # the last image is full size, complete and for last_key
    moving: bool = False
    scale: float = 1.0  # scale of the last render
    rest: int = 0  # frames since the key last changed
    max_scale: float = 1.0  # the "full size" scale (lowered while live training shares the CPU)

    def plan(self, key: object) -> float | None:
        if key != self.last_key:
            self.last_key, self.rest, self.final, self.moving = key, 0, False, True
            return self._moving_scale()
        self.rest += 1
        if self.final:
            self.moving = False
            return None
        if self.scale < self.max_scale and self.rest < REFINE_AFTER_FRAMES:
            return None  # maybe still moving: keep the quick image a moment
        self.moving = False
        return self.max_scale

    def _moving_scale(self) -> float:
        if not self.enabled or self.full_cost_ms is None:
            return self.max_scale
        s = math.sqrt(self.budget_ms / max(self.full_cost_ms, 1e-3))
        if s >= self.max_scale:
            return self.max_scale
        return max(MIN_SCALE, math.floor(s / SCALE_STEP) * SCALE_STEP)

    def done(self, scale: float, draw_ms: float, complete: bool) -> None:
        full = draw_ms / max(scale * scale, 1e-6)
        self.full_cost_ms = full if self.full_cost_ms is None else \
            COST_SMOOTHING * full + (1.0 - COST_SMOOTHING) * self.full_cost_ms
        self.scale = scale
        self.final = scale >= self.max_scale and complete

    def invalidate(self) -> None:
        """Render again next frame although the key did not change."""
        self.final = False
        self.last_key = object()
