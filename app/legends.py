"""Colour bars for the 3D view's heatmaps: which colour means what, with units.

``legend(viewer)`` describes the bar for the current debug/splat mode (None for plain colour);
the viewer draws it over the bottom of the 3D image. The colours come from ``turbo``, the same
polynomial as shaders/colormap.glsl, so the bar matches the pixels.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# Accumulated opacity below which the hole map tints a pixel (app.gl.splats.resolve's default
# hole_alpha, the value shaders/heatmap.frag receives).
HOLE_ALPHA = 0.5
# The note of a map computed for a resting view while the view moves.
STALE = "stale: the view changed; recomputed when it rests"
UNDETERMINED_TITLE = "undetermined (0 .. 1): the two fields disagree,\nthe train views do not determine the scene here"
# shaders/colormap.glsl's polynomial fit of turbo, coefficients per channel (x^0..x^5).
_TURBO = np.array([[0.13572138, 4.61539260, -42.66032258, 132.13108234, -152.94239396, 59.28637943],
                   [0.09140261, 2.19418839, 4.84296658, -14.18503333, 4.27729857, 2.82956604],
                   [0.10667330, 12.64194608, -60.58204836, 110.36276771, -89.90310912, 27.34824973]])


def turbo(x: np.ndarray | float) -> np.ndarray:
    """(..., 3) RGB in [0, 1] of the turbo colormap at x in [0, 1] (as the shaders compute it)."""
    x = np.clip(np.asarray(x, np.float64), 0.0, 1.0)
    powers = np.stack([x ** k for k in range(6)], -1)
    return np.clip(powers @ _TURBO.T, 0.0, 1.0)


@dataclass(frozen=True)
class Legend:
    """A colour bar: ``title`` with its unit, values ``lo`` .. ``hi`` left to right, ``reverse``
    when the map runs high-to-low (depth: near is red), ``kind`` "turbo" | "grey" | "holes"
    (the red tint of the hole map over accumulated opacity lo..hi) | "swatch" (one colour with
    a meaning: the mask), ``note`` an extra line (e.g. a stale map, the masked frames)."""

    title: str
    lo: float = 0.0
    hi: float = 1.0
    kind: str = "turbo"
    reverse: bool = False
    note: str = ""
    color: tuple[float, float, float] = (1.0, 0.0, 0.0)

    def colors(self, n: int) -> np.ndarray:
        """(n, 3) colours of the bar from left to right."""
        x = np.linspace(0.0, 1.0, n)
        if self.kind == "grey":
            return np.repeat(x[:, None], 3, 1)
        if self.kind == "swatch":
            return np.tile(np.asarray(self.color, float), (n, 1))
        if self.kind == "holes":  # shaders/heatmap.frag over a mid-grey pixel: 0.35 + 0.65 (1 - a / 0.5)
            a = self.lo + x * (self.hi - self.lo)
            w = np.where(a < HOLE_ALPHA, 0.35 + 0.65 * np.clip((HOLE_ALPHA - a) / HOLE_ALPHA, 0, 1), 0.0)
            return (1.0 - w)[:, None] * 0.5 + w[:, None] * np.asarray([1.0, 0.0, 0.0])
        return turbo(1.0 - x if self.reverse else x)

    def ticks(self, count: int = 3) -> list[tuple[float, str]]:
        """(position 0..1 along the bar, label) of the numbers under it; none for a swatch."""
        if self.kind == "swatch":
            return []
        return [(k / (count - 1), f"{self.lo + (self.hi - self.lo) * k / (count - 1):.3g}") for k in range(count)]


def legend(viewer) -> Legend | None:
    """The bar for what the 3D view shows now (resolve mode first, then the splat colour mode)."""
    st = viewer.state
    seconds_per_clip = st.num_frames / max(st.fps, 1e-9)  # clip time 1 = the whole clip
    mode = st.debug_mode
    if mode == "depth":
        near, far = viewer.depth_range
        return Legend("depth along the view (scene units): near red, far blue", near, far, reverse=True)
    if mode == "alpha":
        return Legend("accumulated opacity", 0.0, 1.0, kind="grey")
    if mode == "holes":
        return Legend(f"holes: accumulated opacity (red below {HOLE_ALPHA:g}, stronger = emptier)", 0.0, 1.0,
                      kind="holes")
    if mode == "blur":
        note = "" if not viewer.map_stale else STALE
        return Legend("missing detail vs the nearest real view (|Laplacian|, intensity/px^2)", 0.0, viewer.blur_max,
                      note=note)
    if mode == "undetermined":
        return Legend(UNDETERMINED_TITLE, 0.0, 1.0, note=_undetermined_note(viewer))
    if mode == "moving":
        return Legend("moving content (init masks) in magenta; masked:", kind="swatch", color=(1.0, 0.2, 0.9),
                      note=viewer.mask_note)
    if st.splat_mode == "speed":
        return Legend("Gaussian speed |dmu/dt| (scene units per second)", 0.0, viewer.heat_scale / seconds_per_clip)
    if st.splat_mode == "temporal_opacity":
        return Legend("temporal opacity factor at this time", 0.0, 1.0)
    return None


def _undetermined_note(viewer) -> str:
    """How to get a twin field (none beside the model), "stale" (the view moved) or the share
    of the view's pixels the map marks."""
    from app.undetermined import UNDETERMINED_LEVEL, twin_note

    missing = twin_note(viewer)
    if missing:
        return missing
    if viewer.map_stale:
        return STALE
    return f"{100.0 * viewer.undetermined_share:.1f}% of the view undetermined (map >= {UNDETERMINED_LEVEL:g})"
