"""Where a Trainer optimizes: ``TrainingConfig.device`` resolved against the machine.

    device = training_device("auto", "auto")   # torch.device("cuda") with gsplat, else "cpu"

The model, its optimizer state, the densification statistics and the loss live on that device
while a Trainer steps; on CUDA the train views' frames, their moving-pixel weights and camera
matrices are copied over once (fixer4d.train.trainer), stage 2's cached pseudo-targets one
frame at a time. Everything the pipeline's stages hand on (saved PLYs, returned
models, checkpoints on disk) is in host memory, so a CUDA-trained stage is read by every later
stage, by the viewer and on a machine without a GPU alike.

CUDA training rasterizes with gsplat (the "reference" and "cpu" backends take host tensors only),
so "auto" takes CUDA only where torch sees a GPU and gsplat is installed.
"""
from __future__ import annotations

import torch

from fixer4d.errors import BackendUnavailable, InputError

DEVICES = ("auto", "cpu", "cuda")
# Render backends that rasterize CUDA tensors ("auto" means gsplat there).
CUDA_BACKENDS = ("auto", "gsplat")

__all__ = ["DEVICES", "CUDA_BACKENDS", "training_device", "device_kind"]


def training_device(device: str, backend: str) -> torch.device:
    """The torch.device a Trainer with ``TrainingConfig(device=device, backend=backend)`` uses.

    "cpu": the CPU. "cuda": the current CUDA device; BackendUnavailable when CUDA or gsplat is
    missing, InputError for a backend that renders host tensors only ("cpu", "reference").
    "auto": CUDA when it and gsplat are available and the backend is "auto" or "gsplat", else
    the CPU.
    """
    if device not in DEVICES:
        raise InputError(f"TrainingConfig.device {device!r}: choose one of {', '.join(DEVICES)}")
    if device == "cpu":
        return torch.device("cpu")
    from fixer4d.render import gsplat_backend

    if device == "auto":
        if backend in CUDA_BACKENDS and gsplat_backend.unavailable_reason() is None:
            return torch.device("cuda")
        return torch.device("cpu")
    if backend not in CUDA_BACKENDS:
        raise InputError(f"TrainingConfig.device 'cuda' with backend {backend!r}: that backend renders host tensors "
                         f"only; use backend {' or '.join(CUDA_BACKENDS)}, or device cpu")
    if not torch.cuda.is_available():
        raise BackendUnavailable("TrainingConfig.device 'cuda': CUDA is not available (torch.cuda.is_available() is "
                                 "False); set training.device=cpu or auto")
    reason = gsplat_backend.unavailable_reason()
    if reason is not None:
        raise BackendUnavailable(f"TrainingConfig.device 'cuda' rasterizes with gsplat: {reason}")
    return torch.device("cuda")


def device_kind(device: str, backend: str) -> str:
    """"cpu" or "cuda": where a training with ``TrainingConfig(device=device, backend=backend)``
    runs on this machine, the device part of its result's provenance (CUDA and the CPU give other
    last digits). A requested "cuda" is taken as asked; ``training_device`` checks it is there."""
    if device == "auto":
        return training_device(device, backend).type
    if device not in DEVICES:
        raise InputError(f"TrainingConfig.device {device!r}: choose one of {', '.join(DEVICES)}")
    return device
