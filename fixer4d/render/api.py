"""``render()``: one entry point for every rasterizer backend.

    out = render(snapshot, camera, background=(0, 0, 0), backend="auto")
    out.rgb (H, W, 3), out.alpha (H, W), out.depth (H, W), out.radii (N,), out.means2d (N, 2)

Backends: "reference" (pure torch oracle, fixer4d/render/reference.py), "cpu" (numba kernels with
a hand-written backward, fixer4d/render/cpu.py and cpu_kernels.py), "gsplat" (CUDA, optional) and
"auto" (gsplat for CUDA tensors when it is installed, else cpu, else reference).
"""
from __future__ import annotations

from collections.abc import Sequence

import torch

from fixer4d.errors import BackendUnavailable, InputError
from fixer4d.geometry.camera import Camera
from fixer4d.model.snapshot import Snapshot
from fixer4d.render.constants import ALPHA_MIN
from fixer4d.render.output import RenderOutput  # re-exported: fixer4d.render.api.RenderOutput
from fixer4d.render.project import COLOR_LIMIT, guard_extremes, guard_extremes_traced, project_gaussians

BACKENDS = ("auto", "reference", "cpu", "gsplat")

__all__ = ["BACKENDS", "RenderOutput", "render", "render_batch", "resolve_backend"]


def resolve_backend(backend: str, device: torch.device) -> str:
    """Map "auto" to a concrete backend for tensors on ``device``; validate the others."""
    if backend not in BACKENDS:
        raise InputError(f"unknown render backend {backend!r}; choose one of {', '.join(BACKENDS)}")
    if backend != "auto":
        return backend
    if device.type == "cuda":
        import fixer4d.render.gsplat_backend as gsplat_backend

        if gsplat_backend.unavailable_reason() is None:
            return "gsplat"
        raise BackendUnavailable(f"no CUDA rasterizer for CUDA tensors ({gsplat_backend.unavailable_reason()}); "
                                 "move the snapshot to the CPU or install gsplat")
    import fixer4d.render.cpu as cpu

    return "cpu" if cpu.unavailable_reason() is None else "reference"


def _background(background, dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    """(3,) background colour in ``dtype``; InputError for another size, a NaN/inf value or one
    beyond +-COLOR_LIMIT (it would make every pixel or every gradient non-finite)."""
    if background is None:
        return torch.zeros(3, dtype=dtype, device=device)
    try:
        bg = torch.as_tensor(background, dtype=dtype, device=device).reshape(-1)
    except (TypeError, ValueError, RuntimeError) as exc:
        raise InputError(f"render background must be 3 numbers (RGB), got {background!r} ({exc})") from None
    if bg.numel() != 3:
        raise InputError(f"render background must have 3 values (RGB), got {bg.numel()}")
    if not bool((bg.detach().abs() <= COLOR_LIMIT).all()):  # False for NaN/inf too
        raise InputError(f"render background must be finite RGB values in [0, 1] (|value| <= {COLOR_LIMIT:g}), "
                         f"got {bg.tolist()}")
    return bg


def _check_inputs(snapshot: Snapshot, camera: Camera) -> dict[str, tuple[float, float]]:
    """InputError for a non-Camera, a non-Snapshot, mismatched field shapes, non-float fields or
    opacities outside [0, 1]; NumericalError (Snapshot.check) for NaN/inf parameters. Returns the
    snapshot's ``ranges()`` (one read-back serves every check and ``guard_extremes``)."""
    if not isinstance(camera, Camera):
        raise InputError(f"render: camera must be a fixer4d Camera, got {type(camera).__name__}")
    if not isinstance(snapshot, Snapshot):
        raise InputError(f"render: expected a Snapshot (model.at(t)), got {type(snapshot).__name__}")
    n = snapshot.means.shape[0] if snapshot.means.dim() else -1
    expect = {"means": (n, 3), "quats": (n, 4), "scales": (n, 3), "opacities": (n,), "colors": (n, 3)}
    for name, shape in expect.items():
        t = getattr(snapshot, name)
        if not torch.is_tensor(t) or tuple(t.shape) != shape or not t.is_floating_point():
            raise InputError(f"render: Snapshot.{name} must be a float tensor of shape {shape}, got "
                             f"{getattr(t, 'dtype', type(t).__name__)} {tuple(getattr(t, 'shape', ()))}")
    ranges = snapshot.ranges()
    snapshot.check(ranges)
    if n > 0:
        low, high = ranges["opacities"]
        if low < 0.0 or high > 1.0:
            raise InputError(f"render: opacities must be in [0, 1], got values in [{low}, {high}]")
    return ranges


def render(snapshot: Snapshot, camera: Camera, background: torch.Tensor | tuple | None = None,
           backend: str = "auto") -> RenderOutput:
    """Rasterize ``snapshot`` from ``camera``; differentiable w.r.t. every snapshot field.

    Raises NumericalError for non-finite Gaussian parameters (never renders a NaN image),
    InputError for an unknown backend, a malformed or non-finite background, malformed snapshot
    fields or opacities outside [0, 1], BackendUnavailable when an explicitly requested backend
    cannot run here. The reference backend computes in the snapshot's dtype (float64 for
    gradient checks); the others in float32. Finite inputs give a finite image and finite
    gradients: Gaussians too far or too large to project in float32 are culled, huge colours
    clamped, huge quaternions rescaled (``project.guard_extremes``), in every dtype alike.
    """
    ranges = _check_inputs(snapshot, camera)
    device = snapshot.means.device
    name = resolve_backend(backend, device)
    float64 = name == "reference" and snapshot.means.dtype == torch.float64
    bg = _background(background, torch.float64 if float64 else torch.float32, device)  # checked before any work
    snapshot = guard_extremes(snapshot, camera, ranges)
    if name == "gsplat":
        import fixer4d.render.gsplat_backend as gsplat_backend

        return gsplat_backend.render(snapshot, camera, bg)
    if device.type != "cpu":
        raise BackendUnavailable(f"render backend {name!r} runs on CPU tensors; the snapshot is on {device}")
    if name == "cpu" or snapshot.means.dtype not in (torch.float32, torch.float64):
        snapshot = snapshot.to(dtype=torch.float32)
    if name == "cpu":  # the same projection as numba loops with a hand-written backward
        from fixer4d.render.project_cpu import project_gaussians_cpu

        proj = project_gaussians_cpu(snapshot, camera)
    else:
        proj = project_gaussians(snapshot, camera)
    if proj.means2d.requires_grad:
        proj.means2d.retain_grad()
    if name == "reference":
        from fixer4d.render.reference import rasterize_reference

        color_acc, trans, depth_acc, n_fragments = rasterize_reference(proj, camera.width, camera.height)
    else:
        from fixer4d.render.cpu import rasterize_cpu

        color_acc, trans, depth_acc, n_fragments = rasterize_cpu(proj, camera.width, camera.height)
    alpha = 1.0 - trans
    rgb = color_acc + trans[..., None] * bg
    # every blended pixel has alpha >= ALPHA_MIN, so the clamp only guards empty pixels
    # (depth_acc = 0 there) and keeps the division's gradient finite
    depth = depth_acc / torch.clamp(alpha, min=ALPHA_MIN)
    return RenderOutput(rgb=rgb, alpha=alpha, depth=depth, radii=proj.radii, means2d=proj.means2d,
                        n_fragments=int(n_fragments), backend=name)


def render_batch(snapshot: Snapshot, cameras: Sequence[Camera], background: torch.Tensor,
                 matrices: tuple[torch.Tensor, torch.Tensor] | None = None) -> list[RenderOutput]:
    """``render(snapshot, camera, background, backend="gsplat")`` for each of ``cameras`` (one
    image size), in one gsplat call and without reading a value back to the host, so that a GPU
    trainer's host never waits for the device here. For a caller that checks its snapshot's
    model and its background itself (the trainer: once, and every few steps), since ``render``'s
    input checks each read values back; the snapshot passes through ``guard_extremes_traced``.
    ``matrices``: the cameras' (viewmats, Ks) on the snapshot's device
    (``gsplat_backend.camera_matrices``, made once), else they are copied over for this call.
    ``render`` per camera is the reference it is tested against."""
    import fixer4d.render.gsplat_backend as gsplat_backend

    sizes = {(c.width, c.height) for c in cameras}
    if len(sizes) != 1:
        raise InputError(f"render_batch: cameras of one image size, got {sorted(sizes)}")
    (width, height), = sizes
    viewmats, Ks = matrices if matrices is not None else gsplat_backend.camera_matrices(list(cameras),
                                                                                        snapshot.means.device)
    return gsplat_backend.render_batch(guard_extremes_traced(snapshot), viewmats, Ks, width, height, background)
