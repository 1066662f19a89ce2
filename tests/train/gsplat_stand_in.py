"""A ``gsplat`` module for machines without CUDA: ``rasterization`` with gsplat's documented
signature and output shapes for C cameras at once, computed on whatever device its inputs are on
and without reading a value back to the host (so a count of synchronizing calls around it counts
fixer4d's alone). ``install(monkeypatch)`` puts it in place and lets CPU tensors through the
adapter's CUDA checks, so the trainer runs its CUDA code path on the CPU.

The image is the background plus, in every pixel, the opacity-weighted mean colour and GAIN x
the mean projected x coordinate of the camera: differentiable in means (through means2d),
opacities and colours, so a training step's backward and densification statistics have
gradients to carry. Radii are 2 pixels on both axes for Gaussians in front of the near plane.
"""
from __future__ import annotations

import sys
import types

import torch

GAIN = 1e-3
DRAWN_RADIUS = 2


def rasterization(means, quats, scales, opacities, colors, viewmats, Ks, width, height, near_plane=0.01,
                  far_plane=1e10, radius_clip=0.0, eps2d=0.3, sh_degree=None, packed=True, tile_size=16,
                  backgrounds=None, render_mode="RGB", sparse_grad=False, absgrad=False, rasterize_mode="classic",
                  channel_chunk=32, distributed=False, camera_model="pinhole", segmented=False, covars=None):
    cams = viewmats.shape[0]
    in_camera = torch.einsum("cij,nj->cni", viewmats[:, :3, :3], means) + viewmats[:, None, :3, 3]  # (C, N, 3)
    pixels = torch.einsum("cij,cnj->cni", Ks, in_camera)
    means2d = pixels[..., :2] / pixels[..., 2:3]  # (C, N, 2)
    tint = (opacities[:, None] * colors).mean(0)  # (3,)
    shift = GAIN * means2d[..., 0].mean(-1)  # (C,)
    value = tint[None] + shift[:, None] + backgrounds  # (C, 3)
    rgb = value[:, None, None, :].expand(cams, height, width, 3)
    depth = in_camera[..., 2].mean(-1)[:, None, None, None].expand(cams, height, width, 1)
    alphas = opacities.mean().reshape(1, 1, 1, 1).expand(cams, height, width, 1)
    front = (in_camera[..., 2] > near_plane).to(torch.int32) * DRAWN_RADIUS  # (C, N)
    radii = torch.stack([front, front], -1)  # gsplat >= 1.5: per-axis radii (C, N, 2)
    return torch.cat([rgb, depth], -1), alphas, {"radii": radii, "means2d": means2d, "depths": in_camera[..., 2]}


def install(monkeypatch) -> None:
    """Make ``backend="gsplat"`` render CPU tensors through this stand-in for one test."""
    from fixer4d.render import gsplat_backend

    module = types.ModuleType("gsplat")
    module.rasterization = rasterization
    monkeypatch.setitem(sys.modules, "gsplat", module)
    monkeypatch.setattr(gsplat_backend, "unavailable_reason", lambda: None)
    monkeypatch.setattr(gsplat_backend, "_device_problem", lambda device: None)
