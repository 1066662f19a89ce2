"""The constants of the training loss L_STG, shared by its torch reference (losses.py) and its
fused CPU kernel (loss_cpu.py): 3DGS/STGS's training SSIM and the L1 / D-SSIM weighting."""
from __future__ import annotations

import numpy as np

SSIM_WINDOW = 11  # 3DGS/STGS training SSIM window (pixels)
SSIM_SIGMA = 1.5  # Gaussian sigma of that window (pixels), Wang et al. 2004
# Stabilizers of Wang et al. 2004 for data range L = 1: C1 = (0.01 L)^2, C2 = (0.03 L)^2.
SSIM_C1 = 0.01 ** 2
SSIM_C2 = 0.03 ** 2
# L_STG = (1 - LAMBDA_DSSIM) * L1 + LAMBDA_DSSIM * (1 - SSIM): the 3DGS/STGS weighting.
LAMBDA_DSSIM = 0.2


def gaussian_taps() -> np.ndarray:
    """(SSIM_WINDOW,) float64 normalized Gaussian taps of the SSIM window."""
    x = np.arange(SSIM_WINDOW, dtype=np.float64) - (SSIM_WINDOW - 1) / 2.0
    g = np.exp(-(x ** 2) / (2.0 * SSIM_SIGMA ** 2))
    return g / g.sum()
