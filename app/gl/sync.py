"""Waiting for the GL without holding Python's GIL.

moderngl's ``Context.finish()`` (and its draw calls) keep the GIL while they run; on a software
GL (Mesa llvmpipe) finishing a frame can take hundreds of milliseconds, during which every other
Python thread, live training included, stands still (measured: a 1 s splat frame blocked a
spinning thread for 0.97 s). ``glFinish`` called through ctypes releases the GIL for the wait
(measured: longest block 0.07 s, the draw submission). Falls back to ``ctx.finish()`` where no
GL library can be loaded.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import sys
from functools import lru_cache
from typing import Callable

import moderngl

# GL libraries to look ``glFinish`` up in, per platform (the GLVND dispatcher dispatches it to the
# current context, EGL or GLX).
_CANDIDATES = {"linux": ("libGL.so.1", "libOpenGL.so.0"), "darwin": ("/System/Library/Frameworks/OpenGL.framework/OpenGL",),
               "win32": ("opengl32",)}


@lru_cache(maxsize=1)
def _gl_finish() -> Callable[[], None] | None:
    names = list(_CANDIDATES.get(sys.platform, ()))
    found = ctypes.util.find_library("GL")
    if found:
        names.append(found)
    for name in names:
        try:
            fn = ctypes.CDLL(name).glFinish
        except (OSError, AttributeError):
            continue
        fn.restype, fn.argtypes = None, []
        return fn
    return None


def finish(ctx: moderngl.Context) -> None:
    """Block until the GL has executed everything submitted on ``ctx`` (the current context),
    letting other Python threads run meanwhile."""
    fn = _gl_finish()
    if fn is None:
        ctx.finish()
    else:
        fn()
