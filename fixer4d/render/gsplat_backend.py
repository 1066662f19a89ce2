"""gsplat on CUDA, behind the same ``render()`` contract. Importing this module never fails;
gsplat and CUDA are looked up on first use and their absence raises BackendUnavailable.

gsplat's threshold set is the same as fixer4d/render/constants.py for the low-pass (eps2d),
near plane, alpha clamp/skip and early stop; its extent test is per tile rather than per pixel,
so images differ from the CPU backends by at most the faint 3-sigma fringe.

Conventions handed to ``gsplat.rasterization`` (its documented API): C cameras of one image
size (``render``: one; ``render_batch``: a training step's views), the world-to-camera
``viewmats`` (C, 4, 4) in OpenCV axes (x right, y down, z forward, as ``Camera.w2c``) and pixel
intrinsics ``Ks`` (C, 3, 3); the snapshot's activated values
(quaternions wxyz, unnormalized; scales as standard deviations; opacities in [0, 1]; colours
(N, 3) already view-dependent, so ``sh_degree`` None); ``packed=False`` so per-Gaussian outputs
keep the (C, N, ...) layout; "RGB+ED" for colour plus expected depth (gsplat pads the
background with a zero depth channel).
"""
from __future__ import annotations

import functools
import importlib

import numpy as np
import torch

from fixer4d.errors import BackendUnavailable
from fixer4d.geometry.camera import Camera
from fixer4d.model.snapshot import Snapshot
from fixer4d.render.constants import LOWPASS_2D, NEAR_PLANE
from fixer4d.render.output import RenderOutput


def unavailable_reason() -> str | None:
    """None when gsplat can rasterize here, else a sentence saying why not.

    With CUDA and gsplat installed this loads gsplat's CUDA extension: PyPI's gsplat builds it
    with nvcc on first use (about a minute on 16 cores, once per machine), and where it cannot
    (no CUDA toolkit, a failed build) the answer says so, so that "auto" choices fall back to the
    CPU instead of failing at the first render."""
    if not torch.cuda.is_available():
        return "CUDA is not available (torch.cuda.is_available() is False); use backend='cpu'"
    try:
        importlib.import_module("gsplat")
    except ImportError as exc:
        return f"gsplat is not installed ({exc}); `pip install gsplat` on a CUDA machine, or use backend='cpu'"
    return extension_problem()


@functools.lru_cache(maxsize=1)
def extension_problem() -> str | None:
    """None when gsplat's CUDA extension loads, else why not (asked once per process: a failed
    build is not retried at every render)."""
    try:
        backend = importlib.import_module("gsplat.cuda._backend")
    except Exception as exc:  # a failed nvcc/ninja build surfaces as any exception of the import
        return (f"gsplat's CUDA extension failed to build or load ({type(exc).__name__}: {str(exc)[:300]}); "
                "check nvcc and ninja (gsplat builds it on first use), or use backend='cpu'")
    if getattr(backend, "_C", None) is None:
        return ("gsplat's CUDA extension is not built: gsplat found no CUDA toolkit to build it with (it needs "
                "nvcc on first use); install the CUDA toolkit, or use backend='cpu'")
    return None


def _device_problem(device: torch.device) -> str | None:
    """None when gsplat's kernels take tensors on ``device`` (CUDA), else why not."""
    if device.type != "cuda":
        return (f"render backend 'gsplat' needs CUDA tensors; the snapshot is on {device} "
                f"(use snapshot.to('cuda') or backend='cpu')")
    return None


def render(snapshot: Snapshot, camera: Camera, background: torch.Tensor) -> RenderOutput:
    """Rasterize with ``gsplat.rasterization``; background: (3,) RGB."""
    snap = snapshot.to(dtype=torch.float32)
    viewmats, Ks = camera_matrices([camera], snap.means.device)
    (out,) = render_batch(snap, viewmats, Ks, camera.width, camera.height, background)
    return out


def camera_matrices(cameras: list[Camera], device: torch.device) -> tuple[torch.Tensor, torch.Tensor]:
    """(C, 4, 4) world-to-camera ``viewmats`` and (C, 3, 3) ``Ks`` of ``cameras`` on ``device``,
    float32, as ``rasterization`` takes them (one host-to-device copy each: a trainer makes
    them once for its cameras)."""
    viewmats = torch.from_numpy(np.stack([c.w2c for c in cameras]).astype(np.float32))
    Ks = torch.from_numpy(np.stack([c.K for c in cameras]).astype(np.float32))
    return viewmats.to(device), Ks.to(device)


def render_batch(snapshot: Snapshot, viewmats: torch.Tensor, Ks: torch.Tensor, width: int, height: int,
                 background: torch.Tensor) -> list[RenderOutput]:
    """One ``rasterization`` call for C cameras of one image size (``camera_matrices``): one
    RenderOutput per camera. Reads no value back to the host."""
    reason = unavailable_reason()
    if reason is not None:
        raise BackendUnavailable(f"render backend 'gsplat' unavailable: {reason}")
    problem = _device_problem(snapshot.means.device)
    if problem is not None:
        raise BackendUnavailable(problem)
    from gsplat import rasterization

    snap = snapshot.to(dtype=torch.float32)
    cams = viewmats.shape[0]
    colors, alphas, meta = rasterization(
        snap.means, snap.quats, snap.scales, snap.opacities, snap.colors, viewmats, Ks,
        int(width), int(height), near_plane=NEAR_PLANE, eps2d=LOWPASS_2D, render_mode="RGB+ED",
        backgrounds=background.to(torch.float32)[None].expand(cams, 3), packed=False, rasterize_mode="classic")
    radii = meta["radii"]
    if radii.dim() == 3:  # gsplat >= 1.5 stores per-axis radii
        radii = radii.max(dim=-1).values
    radii = radii.to(torch.int32)
    means2d = _means2d_with_grad(meta["means2d"])
    return [RenderOutput(rgb=colors[c, ..., :3], alpha=alphas[c, ..., 0], depth=colors[c, ..., 3], radii=radii[c],
                         means2d=means2d[c], n_fragments=-1, backend="gsplat") for c in range(cams)]


def _means2d_with_grad(full: torch.Tensor) -> list[torch.Tensor]:
    """Per camera, the (N, 2) projected centres of gsplat's (C, N, 2) ``means2d``, whose ``.grad``
    receives dL/dmeans2d (N, 2) of that camera on backward, as the CPU backends' means2d does
    (densification statistics).

    gsplat rasterizes from the (C, N, 2) tensor itself, so a view of it is off the loss's graph
    and would never get a gradient: a hook on the full tensor passes each camera's gradient on
    (added up over several backward passes, as a retained gradient is). The returned tensors are
    detached.
    """
    carriers = list(full.detach().unbind(0))
    if full.requires_grad:
        def pass_on(grad: torch.Tensor) -> None:
            for carrier, g in zip(carriers, grad.unbind(0)):
                carrier.grad = g.clone() if carrier.grad is None else carrier.grad + g

        full.register_hook(pass_on)
    return carriers
