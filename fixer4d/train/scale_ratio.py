"""The anisotropy penalty on the Gaussians' shapes (``training.scale_ratio_weight``; off).

Four cameras let a Gaussian stretch along a ray that no other camera looks across: from the train
views it reads as a dot or a short stroke, from a free view as a needle (the streaks that fan out at
the edges of an orbit). PhysGaussian (Xie et al., CVPR 2024) bounds the ratio of a Gaussian's
largest to its smallest axis with

    L_ratio = mean over Gaussians of max(s_max / s_min, r) - r

which is 0 for every Gaussian within r : 1 and pulls the longer axes of the others in (the
gradient reaches the log-scales only). ``scale_ratio_penalty`` is that term on the model's (N, 3)
log-scales. Against the shortest axis a flat disc on a wall (two long axes, one short) pays as
much as a needle; against the middle axis (``against="middle"``) only a needle (one long axis, two
short) pays.
"""
from __future__ import annotations

import torch

# The axis the longest is measured against.
AGAINST = ("shortest", "middle")


def scale_ratio_penalty(log_scales: torch.Tensor, max_ratio: float, against: str = "shortest") -> torch.Tensor:
    """Scalar mean over the (N, 3) ``log_scales`` of relu(s_max / s_ref - max_ratio), s_ref the
    shortest or the middle axis (``against``); 0 for N = 0.

    The ratio is taken as exp(log s_max - log s_ref), which stays finite for any finite input that
    a float can hold as a ratio (the model's scales are bounded: model.snapshot's guards)."""
    if log_scales.shape[0] == 0:
        return log_scales.sum() * 0.0
    ordered = torch.sort(log_scales, dim=1).values
    spread = ordered[:, 2] - ordered[:, AGAINST.index(against)]
    return torch.relu(torch.exp(spread) - max_ratio).mean()


__all__ = ["AGAINST", "scale_ratio_penalty"]
