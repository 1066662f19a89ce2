"""The plane sweep's multi-view consistency check: a depth stays valid when other views'
depths, sampled where it projects, re-project back onto it (forward-backward, in pixels and
relative depth). Torch on CPU, computed in float64."""
from __future__ import annotations

from typing import Sequence

import numpy as np
import torch

from fixer4d.geometry.camera import Camera


def geometric_consistency(depths: list[torch.Tensor], valids: list[torch.Tensor], cams: Sequence[Camera],
                          pixel_tol: float, depth_tol: float, min_views: int) -> list[torch.Tensor]:
    """Forward-backward check: a reference depth stays valid when at least ``min_views`` other
    views, sampled where it projects, re-project back within ``pixel_tol`` pixels and
    ``depth_tol`` relative depth.

    depths: V (H, W) z-depths; valids: V (H, W) bool; cams: the V cameras at the depths'
    resolution. Returns V (H, W) bool, the valid pixels that pass."""
    out = []
    for r, cam_r in enumerate(cams):
        d_r = depths[r].to(torch.float64)
        v_r = valids[r]
        H, W = d_r.shape
        idx = torch.nonzero(v_r.reshape(-1)).squeeze(1)
        count = torch.zeros(idx.shape[0], dtype=torch.int32)
        if idx.numel() == 0:
            out.append(v_r.clone())
            continue
        pix = torch.from_numpy(cam_r.pixel_centers().reshape(-1, 2))[idx]
        z = d_r.reshape(-1)[idx]
        X = torch.from_numpy(cam_r.backproject(pix.numpy(), z.numpy()))
        for s, cam_s in enumerate(cams):
            if s == r:
                continue
            uv_s, z_s = (torch.from_numpy(a) for a in cam_s.project(X.numpy()))
            iu = torch.floor(uv_s[:, 0]).long()
            iv = torch.floor(uv_s[:, 1]).long()
            ok = (z_s > 0) & (iu >= 0) & (iu < cam_s.width) & (iv >= 0) & (iv < cam_s.height)
            ok &= torch.isfinite(uv_s).all(1)
            flat = (iv.clamp(0, cam_s.height - 1) * cam_s.width + iu.clamp(0, cam_s.width - 1))
            d_s = depths[s].to(torch.float64).reshape(-1)[flat]
            ok &= valids[s].reshape(-1)[flat]
            # pixels already rejected back-project from (0, 0) at depth 1: their non-finite uv or depth
            # would only warn
            keep = ok.numpy()
            Y = cam_s.backproject(np.where(keep[:, None], uv_s.numpy(), 0.0), np.where(keep, d_s.numpy(), 1.0))
            uv_back, z_back = (torch.from_numpy(a) for a in cam_r.project(Y))
            err = torch.linalg.norm(uv_back - pix, dim=1)
            rel = (z_back - z).abs() / z
            ok &= (err < pixel_tol) & (rel < depth_tol)
            count += ok.to(torch.int32)
        keep = torch.zeros(H * W, dtype=torch.bool)
        keep[idx] = count >= min_views
        out.append(keep.reshape(H, W))
    return out
