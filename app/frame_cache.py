"""Playback at full fidelity: the 3D view's full-quality image of each frame, kept while the
camera rests.

When only the time changes (the timeline plays or is scrubbed with the camera at rest) each
frame is rendered once at full quality (every splat, exact depth order, full size) and its
displayed image copied into a texture here; later passes over that frame show the texture.
Anything else the image depends on (camera, model, edits, modes, overlays, size) is the cache's
``base`` key: a new base empties it. The textures take at most ``budget_bytes``; beyond that the
least recently shown frame goes.
"""
from __future__ import annotations

from collections import OrderedDict
from typing import Any, Hashable

import moderngl

# Memory for cached frames (bytes). At 1280x720 RGBA8 a frame is 3.7 MB, so 384 MB hold ~100
# frames: the demo's clip and the tiny scenes whole, a long clip's most recent ~3 s at 30 fps,
# while staying a small share of the RAM a software GL (llvmpipe) uses for textures.
FRAME_CACHE_BYTES = 384 * 1024 * 1024


class FrameCache:
    """Full-quality frames for one ``base`` view: ``get(base, frame)`` -> texture or None,
    ``put(base, frame, source_fbo)`` copies the framebuffer's image in."""

    def __init__(self, ctx: moderngl.Context, budget_bytes: int = FRAME_CACHE_BYTES) -> None:
        self.ctx = ctx
        self.budget_bytes = int(budget_bytes)
        self.base: Hashable = None
        self._frames: OrderedDict[Any, tuple[moderngl.Texture, moderngl.Framebuffer]] = OrderedDict()
        self.bytes = 0
        self.fill_ms = 0.0  # time spent rendering frames into the cache since the base changed
        self.hits = 0
        self.misses = 0

    def __len__(self) -> int:
        return len(self._frames)

    def _rebase(self, base: Hashable) -> None:
        if base != self.base:
            self.clear()
            self.base = base

    def get(self, base: Hashable, frame: Any) -> moderngl.Texture | None:
        self._rebase(base)
        hit = self._frames.get(frame)
        if hit is None:
            self.misses += 1
            return None
        self._frames.move_to_end(frame)
        self.hits += 1
        return hit[0]

    def put(self, base: Hashable, frame: Any, source: moderngl.Framebuffer, render_ms: float = 0.0) -> moderngl.Texture:
        """Copy ``source``'s colour image (the displayed frame) in as ``frame``'s texture."""
        self._rebase(base)
        w, h = source.size
        size = 4 * w * h
        if frame in self._frames:
            self._drop(frame)
        while self._frames and self.bytes + size > self.budget_bytes:
            self._drop(next(iter(self._frames)))
        tex = self.ctx.texture((w, h), 4)
        fbo = self.ctx.framebuffer(color_attachments=[tex])
        self.ctx.copy_framebuffer(fbo, source)
        self._frames[frame] = (tex, fbo)
        self.bytes += size
        self.fill_ms += render_ms
        return tex

    def _drop(self, frame: Any) -> None:
        tex, fbo = self._frames.pop(frame)
        self.bytes -= 4 * tex.size[0] * tex.size[1]
        fbo.release()
        tex.release()

    def clear(self) -> None:
        while self._frames:
            self._drop(next(iter(self._frames)))
        self.bytes = 0
        self.fill_ms = 0.0
        self.hits = self.misses = 0
        self.base = None

    def release(self) -> None:
        self.clear()
