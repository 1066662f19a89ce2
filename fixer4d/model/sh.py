"""View-dependent colour: real spherical harmonics in the 3DGS / graphics convention, degree 0..3.

A Gaussian's colour seen from a camera centre c is, per channel,

    max(0.5 + SH_C0 dc + sum_k Y_k(d) rest_k, 0),   d = (mean - c) / |mean - c|

with dc (N, 3) the DC coefficients and rest (N, (degree + 1)^2 - 1, 3) the higher bands.
"""
from __future__ import annotations

import numpy as np
import torch

# Real spherical-harmonics constants (the 3DGS / graphics convention), degree 0..3.
SH_C0 = 0.28209479177387814
SH_C1 = 0.4886025119029199
SH_C2 = (1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792, 0.5462742152960396)
SH_C3 = (-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154,
         -0.4570457994644658, 1.445305721320277, -0.5900435899266435)

MAX_SH_DEGREE = 3  # the 3DGS maximum; higher bands overfit 4 views

# Directions for view-dependent colour: a Gaussian at the camera centre has no direction; the
# eps turns that 0/0 into a zero direction (DC colour only) instead of NaN.
DIRECTION_EPS = 1e-12


def rgb_to_sh_dc(rgb: torch.Tensor | np.ndarray) -> torch.Tensor | np.ndarray:
    """RGB in [0, 1] -> SH DC coefficients (inverse of 0.5 + C0 * dc)."""
    return (rgb - 0.5) / SH_C0


def sh_basis(dirs: torch.Tensor, degree: int) -> torch.Tensor:
    """Real SH basis without the DC term: (M, 3) unit directions -> (M, (degree+1)^2 - 1)."""
    x, y, z = dirs.unbind(-1)
    out = [-SH_C1 * y, SH_C1 * z, -SH_C1 * x]
    if degree > 1:
        xx, yy, zz = x * x, y * y, z * z
        out += [SH_C2[0] * x * y, SH_C2[1] * y * z, SH_C2[2] * (2.0 * zz - xx - yy),
                SH_C2[3] * x * z, SH_C2[4] * (xx - yy)]
        if degree > 2:
            out += [SH_C3[0] * y * (3.0 * xx - yy), SH_C3[1] * x * y * z, SH_C3[2] * y * (4.0 * zz - xx - yy),
                    SH_C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy), SH_C3[4] * x * (4.0 * zz - xx - yy),
                    SH_C3[5] * z * (xx - yy), SH_C3[6] * x * (xx - 3.0 * yy)]
    return torch.stack(out, -1)


def sh_colors(dc: torch.Tensor, rest: torch.Tensor | None, degree: int, means: torch.Tensor,
              camera_center: np.ndarray | None) -> torch.Tensor:
    """(N, 3) RGB of N Gaussians at ``means`` (N, 3) seen from ``camera_center`` (3,) (module
    docstring). rest: (N, (degree+1)^2 - 1, 3), unused (may be None) when degree is 0; with no
    camera centre the colour is the view-independent DC term."""
    rgb = SH_C0 * dc
    if degree > 0 and camera_center is not None:
        c = torch.as_tensor(np.asarray(camera_center, dtype=np.float64).reshape(3),
                            dtype=means.dtype, device=means.device)
        d = means - c
        d = d / torch.sqrt((d * d).sum(-1, keepdim=True) + DIRECTION_EPS)
        basis = sh_basis(d, degree)  # (N, K)
        rgb = rgb + torch.einsum("nk,nkc->nc", basis, rest)
    return torch.clamp_min(rgb + 0.5, 0.0)
