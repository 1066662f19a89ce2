"""gsplat on CUDA, behind the same ``render()`` contract. Importing this module never fails;
gsplat and CUDA are looked up on first use and their absence raises BackendUnavailable.

gsplat's threshold set is the same as fixer4d/render/constants.py for the low-pass (eps2d),
near plane, alpha clamp/skip and early stop; its extent test is per tile rather than per pixel,
so images differ from the CPU backends by at most the faint 3-sigma fringe.
"""
from __future__ import annotations

import importlib

import torch

from fixer4d.errors import BackendUnavailable
from fixer4d.geometry.camera import Camera
from fixer4d.model.snapshot import Snapshot
from fixer4d.render.constants import LOWPASS_2D, NEAR_PLANE
from fixer4d.render.output import RenderOutput


def unavailable_reason() -> str | None:
    """None when gsplat can rasterize here, else a sentence saying why not."""
    if not torch.cuda.is_available():
        return "CUDA is not available (torch.cuda.is_available() is False); use backend='cpu'"
    try:
        importlib.import_module("gsplat")
    except ImportError as exc:
        return f"gsplat is not installed ({exc}); `pip install gsplat` on a CUDA machine, or use backend='cpu'"
    return None


def render(snapshot: Snapshot, camera: Camera, background: torch.Tensor):
    """Rasterize with ``gsplat.rasterization``; returns fixer4d.render.output.RenderOutput."""
    reason = unavailable_reason()
    if reason is not None:
        raise BackendUnavailable(f"render backend 'gsplat' unavailable: {reason}")
    if snapshot.means.device.type != "cuda":
        raise BackendUnavailable(f"render backend 'gsplat' needs CUDA tensors; the snapshot is on "
                                 f"{snapshot.means.device} (use snapshot.to('cuda') or backend='cpu')")
    from gsplat import rasterization

    snap = snapshot.to(dtype=torch.float32)
    device = snap.means.device
    viewmat = torch.tensor(camera.w2c.copy(), dtype=torch.float32, device=device)[None]
    K = torch.tensor(camera.K.copy(), dtype=torch.float32, device=device)[None]
    colors, alphas, meta = rasterization(
        snap.means, snap.quats, snap.scales, snap.opacities, snap.colors, viewmat, K,
        camera.width, camera.height, near_plane=NEAR_PLANE, eps2d=LOWPASS_2D, render_mode="RGB+ED",
        backgrounds=background.to(torch.float32)[None], packed=False, rasterize_mode="classic")
    means2d = meta["means2d"]
    if means2d.requires_grad:
        means2d.retain_grad()
    radii = meta["radii"][0]
    if radii.dim() == 2:  # gsplat >= 1.5 stores per-axis radii
        radii = radii.max(dim=-1).values
    return RenderOutput(rgb=colors[0, ..., :3], alpha=alphas[0, ..., 0], depth=colors[0, ..., 3],
                        radii=radii.to(torch.int32), means2d=means2d[0], n_fragments=-1, backend="gsplat")
