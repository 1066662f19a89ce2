"""Differentiable Gaussian rasterization: ``render(snapshot, camera, background, backend)``.

See fixer4d/render/api.py for the entry point and fixer4d/render/constants.py for the shared
thresholds.
"""
from fixer4d.render.api import BACKENDS, RenderOutput, render, resolve_backend

__all__ = ["BACKENDS", "RenderOutput", "render", "resolve_backend"]
