"""The plane sweep's matching cost: aggregated top-k ZNCC of reference tiles against source
views warped through plane-induced homographies.

``plane_scores_torch`` is the readable torch reference; ``plane_scores_kernel`` computes the same
scores through the numba kernel (fixer4d.init.mvs_kernel), tested against it. Both take the
reference tiles (``RefView``), the source views (``SourceView``), the homography terms of every
source and the planes' inverse depths, and return (n planes, B tiles, h, w) float32 scores.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch
import torch.nn.functional as F

from fixer4d.geometry.camera import Camera
import fixer4d.init.constants as C


def _box(x: torch.Tensor, k: int) -> torch.Tensor:
    """Mean over a k x k window of (B, C, H, W), shrinking at the borders (no zero padding bias).

    Separable sums of shifted slices added in place, divided by the per-pixel count of in-image
    taps: the per-axis counts multiply to the 2D count, so the mean is exact. (5x faster than
    ``avg_pool2d(count_include_pad=False)`` on CPU at 7x7, measured in one process.)"""
    if k <= 1:
        return x
    r = k // 2
    H, W = x.shape[-2:]
    s = x.clone()
    for i in range(1, min(r, W - 1) + 1):
        s[..., :-i] += x[..., i:]
        s[..., i:] += x[..., :-i]
    t = s.clone()
    for i in range(1, min(r, H - 1) + 1):
        t[..., :-i, :] += s[..., i:, :]
        t[..., i:, :] += s[..., :-i, :]
    return t.mul_(_inv_box_count(H, W, k))


def _inv_box_count(H: int, W: int, k: int) -> torch.Tensor:
    """(H, W) 1 / number of in-image taps of a k x k window centred on each pixel."""
    r = k // 2

    def axis(n: int) -> torch.Tensor:
        i = torch.arange(n)
        return (torch.minimum(i, torch.tensor(r)) + torch.minimum(n - 1 - i, torch.tensor(r)) + 1).to(torch.float32)

    return 1.0 / (axis(H)[:, None] * axis(W)[None, :])


@dataclass
class SourceView:
    """One source view at one pyramid level: (1, 1, H, W) gray and its camera."""

    gray: torch.Tensor
    cam: Camera


class RefView:
    """B reference images or tiles (B, 1, h, w) with their windowed mean, variance (B, h, w)
    and texture test."""

    def __init__(self, gray: torch.Tensor, window: int, min_patch_std: float) -> None:
        self.gray = gray.contiguous()
        self.height, self.width = gray.shape[-2:]
        self.window = window
        self.mu = _box(self.gray, window)[:, 0]
        self.var = (_box(self.gray * self.gray, window)[:, 0] - self.mu * self.mu).clamp_min(0.0)
        self.textured = self.var.sqrt() >= min_patch_std


def pixel_grid(x0: int, y0: int, h: int, w: int) -> torch.Tensor:
    """(2, h w) float64 pixel centres (u + 0.5, v + 0.5) of the h x w block at (x0, y0)."""
    v, u = torch.meshgrid(torch.arange(y0, y0 + h, dtype=torch.float64) + 0.5,
                          torch.arange(x0, x0 + w, dtype=torch.float64) + 0.5, indexing="ij")
    return torch.stack([u.reshape(-1), v.reshape(-1)])


def homography_terms(cam_r: Camera, cam_s: Camera, pix: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Source pixel x_s ~ A p + w b for reference pixel centres ``pix`` (2, N) (p = (u, v, 1),
    coordinates of ``cam_r``'s image) at inverse depth w: A (3, N), b (3, 1) float32."""
    ph = torch.cat([pix, torch.ones(1, pix.shape[1], dtype=pix.dtype)], 0)  # (3, N) float64
    rel = cam_s.w2c @ cam_r.c2w  # reference camera -> source camera
    Ks = torch.tensor(cam_s.K)
    A = (Ks @ torch.tensor(rel[:3, :3] @ np.linalg.inv(cam_r.K))) @ ph
    b = Ks @ torch.tensor(rel[:3, 3])
    return A.to(torch.float32), b.to(torch.float32)[:, None]


def plane_scores_torch(ref: RefView, sources: list[SourceView], geo, ws: torch.Tensor, topk: int,
                       aggregation: int) -> torch.Tensor:
    """Aggregated top-k ZNCC of B reference tiles (``ref``, (B, 1, h, w)) on planes of inverse
    depth ``ws`` (n, B) (or (n, 1): the same planes for every tile) -> (n, B, h, w) float32.

    geo: per source (A (3, B h w), b (3, 1)) from ``homography_terms``: the source pixel of a
    reference pixel p at inverse depth w is x_s ~ A p + w b. topk: best sources averaged per
    plane; aggregation: box side of the cost aggregation (1 = none)."""
    B, h, w = ref.gray.shape[0], ref.height, ref.width
    n = ws.shape[0]
    k = min(topk, len(sources))
    per_source = []
    total = worst = None
    for src, (A, b) in zip(sources, geo):
        Ws, Hs = src.cam.width, src.cam.height
        A = A.reshape(3, 1, B, h * w)
        wb = ws[:, :, None]  # (n, B, 1)
        z = A[2] + wb * b[2]  # (n, B, hw)
        grid = torch.empty((n, B, h * w, 2))
        u, v = grid[..., 0], grid[..., 1]
        torch.div(A[0] + wb * b[0], z, out=u)
        torch.div(A[1] + wb * b[1], z, out=v)
        inside = (z > 0) & (u >= 0) & (u <= Ws) & (v >= 0) & (v <= Hs)
        u.mul_(2.0 / Ws).sub_(1.0)
        v.mul_(2.0 / Hs).sub_(1.0)
        grid.masked_fill_(~inside[..., None], -2.0)
        warped = F.grid_sample(src.gray, grid.view(1, n * B * h, w, 2), mode="bilinear",
                               padding_mode="zeros", align_corners=False).view(n, B, h, w)
        # one box filter for the windowed means (and the inside share where a warp leaves the image)
        c = 3 if bool(inside.all()) else 4
        buf = torch.empty((n * B, c, h, w))
        bv = buf.view(n, B, c, h, w)
        bv[:, :, 0] = warped
        torch.mul(warped, warped, out=bv[:, :, 1])
        torch.mul(warped, ref.gray[:, 0], out=bv[:, :, 2])
        if c == 4:
            bv[:, :, 3] = inside.view(n, B, h, w)
        means = _box(buf, ref.window).view(n, B, c, h, w)
        mu_s = means[:, :, 0]
        var_s = (means[:, :, 1] - mu_s * mu_s).clamp_min_(0.0)
        cross = means[:, :, 2] - mu_s * ref.mu
        zncc = cross.div_(torch.sqrt(var_s.mul_(ref.var).add_(C.MVS_ZNCC_EPS)))
        if c == 4:
            zncc.masked_fill_(means[:, :, 3] < C.MVS_MIN_INSIDE, -1.0)
        if k == len(sources) - 1:  # the mean of all but the worst source: running sum and minimum
            total = zncc.clone() if total is None else total.add_(zncc)
            worst = zncc if worst is None else torch.minimum(worst, zncc)
        else:
            per_source.append(zncc)
    if per_source:
        stack = torch.stack(per_source, 0)  # (S, n, B, h, w)
        score = stack.mean(0) if k == stack.shape[0] else stack.topk(k, dim=0).values.mean(0)
    else:
        score = total.sub_(worst).div_(k)
    return _box(score.reshape(n * B, 1, h, w), aggregation).reshape(n, B, h, w)


def plane_scores_kernel(ref: RefView, sources: list[SourceView], geo, ws: torch.Tensor, topk: int,
                        aggregation: int) -> torch.Tensor:
    """``plane_scores_torch`` through fixer4d.init.mvs_kernel.zncc_scores (same arguments)."""
    from fixer4d.init.mvs_kernel import zncc_scores
    from fixer4d.jit import torch_threads_kept

    B, h, w = ref.gray.shape[0], ref.height, ref.width
    S = len(sources)
    Hmax = max(s.cam.height for s in sources)
    Wmax = max(s.cam.width for s in sources)
    srcs = np.zeros((S, Hmax, Wmax), np.float32)
    size = np.zeros((S, 2), np.int64)
    for i, src in enumerate(sources):
        g = src.gray[0, 0].numpy()
        srcs[i, :g.shape[0], :g.shape[1]] = g
        size[i] = g.shape
    A = np.ascontiguousarray(np.stack([a.numpy() for a, _ in geo]), np.float32)
    bvec = np.ascontiguousarray(np.stack([b[:, 0].numpy() for _, b in geo]), np.float32)
    out = np.empty((ws.shape[0], B, h, w), np.float32)
    f32 = np.float32
    with torch_threads_kept():
        zncc_scores(np.ascontiguousarray(ref.gray[:, 0].numpy()), np.ascontiguousarray(ref.mu.numpy()),
                    np.ascontiguousarray(ref.var.numpy()), srcs, size, A, bvec,
                    np.ascontiguousarray(ws.numpy(), np.float32), ref.window, aggregation,
                    min(topk, S), f32(C.MVS_ZNCC_EPS), f32(C.MVS_MIN_INSIDE), out)
    return torch.from_numpy(out)
