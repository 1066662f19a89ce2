"""The static snapshot of a Gaussian model at one time: what every renderer consumes.

``SpacetimeGaussians.at(t)`` produces one; the torch rasterizers, the gsplat backend and the GL
viewer all read the same fields. Tensors may carry autograd history back to the model.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields

import torch

from fixer4d.errors import NumericalError


@dataclass
class Snapshot:
    """N Gaussians frozen at one instant.

    means: (N, 3) world positions. quats: (N, 4) rotations, (w, x, y, z), not necessarily
    normalized (renderers normalize; zero -> identity). scales: (N, 3) positive standard
    deviations along the local axes (world units). opacities: (N,) in [0, 1] (temporal opacity
    already applied). colors: (N, 3) RGB in [0, 1] (view-dependent colour already evaluated).
    """

    means: torch.Tensor
    quats: torch.Tensor
    scales: torch.Tensor
    opacities: torch.Tensor
    colors: torch.Tensor

    def __len__(self) -> int:
        return int(self.means.shape[0])

    def ranges(self) -> dict[str, tuple[float, float]]:
        """Each field's (min, max) over all its values, read back to the host in one transfer.
        NaN where the field holds a NaN, +-inf where it holds an infinity; empty for N = 0."""
        if len(self) == 0:
            return {}
        with torch.no_grad():
            bounds = torch.stack([torch.stack(getattr(self, f.name).detach().aminmax()).to(torch.float64)
                                  for f in fields(self)]).tolist()
        return {f.name: (lo, hi) for f, (lo, hi) in zip(fields(self), bounds)}

    def check(self, ranges: dict[str, tuple[float, float]] | None = None) -> "Snapshot":
        """Validate shapes and finiteness; raise a clear error instead of rendering NaN.
        ranges: ``self.ranges()`` when the caller has it already (the renderer reads it once for
        this check, the opacity bounds and ``guard_extremes``)."""
        n = len(self)
        expect = {"means": (n, 3), "quats": (n, 4), "scales": (n, 3), "opacities": (n,), "colors": (n, 3)}
        for f in fields(self):
            t = getattr(self, f.name)
            if tuple(t.shape) != expect[f.name]:
                raise ValueError(f"Snapshot.{f.name} has shape {tuple(t.shape)}, expected {expect[f.name]}")
        # a min and a max are finite exactly when every value is (NaN propagates through both)
        ranges = self.ranges() if ranges is None else ranges
        for name, (lo, hi) in ranges.items():
            if not (math.isfinite(lo) and math.isfinite(hi)):
                t = getattr(self, name)
                bad = int((~torch.isfinite(t)).any(dim=-1).sum()) if t.dim() > 1 else int((~torch.isfinite(t)).sum())
                raise NumericalError(f"Snapshot.{name} has non-finite values in {bad} of {n} Gaussians; "
                                     "the model diverged or was loaded from a corrupt file")
        return self

    def detach(self) -> "Snapshot":
        return Snapshot(*(getattr(self, f.name).detach() for f in fields(self)))

    def to(self, device=None, dtype=None) -> "Snapshot":
        return Snapshot(*(getattr(self, f.name).to(device=device, dtype=dtype) for f in fields(self)))

    def subset(self, index: torch.Tensor) -> "Snapshot":
        return Snapshot(*(getattr(self, f.name)[index] for f in fields(self)))

    @staticmethod
    def cat(parts: list["Snapshot"]) -> "Snapshot":
        return Snapshot(*(torch.cat([getattr(p, f.name) for p in parts]) for f in fields(Snapshot)))
