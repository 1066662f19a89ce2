"""The pure-torch rasterizer: the readable oracle every fast backend is checked against.

Front-to-back alpha compositing of depth-sorted splats, written with dense tensor ops so that
autograd provides the backward. Memory stays bounded by working one pixel tile at a time with
only the splats whose extent overlaps that tile (never a pixels x Gaussians tensor for the whole
image). Runs in the dtype of its inputs (float32 or float64).

Blending rule, per pixel, walking splats front to back (identical in every backend):
    power_i = 0.5 (a e^2 + q dy^2), e = dx + r dy      (dx, dy = pixel centre - mean; the
                                                        conic in LDL form, see project.py)
    skip i if power_i > POWER_MAX                       (outside the 3-sigma ellipse)
    alpha_i = min(ALPHA_MAX, opacity_i exp(-power_i)); skip i if alpha_i < ALPHA_MIN
    stop before i if T (1 - alpha_i) < T_MIN, else blend: w_i = alpha_i T, T <- T (1 - alpha_i)
Because T only decreases, "not yet stopped" at i is exactly cumprod_{j<=i}(1 - a_j) >= T_MIN
over the non-skipped a_j, which is how the early stop is written as a mask here.
"""
from __future__ import annotations

import torch
from torch.utils.checkpoint import checkpoint

from fixer4d.render.constants import ALPHA_MAX, ALPHA_MIN, POWER_MAX, T_MIN, TILE
from fixer4d.render.project import Projection

# Pixels per oracle tile edge: larger than the fast kernel's TILE to cut Python overhead; the
# result does not depend on it (the extent test is per pixel).
REFERENCE_TILE = 2 * TILE


def rasterize_reference(proj: Projection, width: int, height: int,
                        tile: int = REFERENCE_TILE) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, int]:
    """Composite projected splats into accumulators.

    Returns (color_acc (H, W, 3) = sum_i w_i c_i, transmittance (H, W) = final T,
    depth_acc (H, W) = sum_i w_i z_i, n_fragments = number of blended (splat, pixel) pairs).
    Differentiable (autograd) w.r.t. means2d, conics, depths, opacities and colors.
    """
    dtype, device = proj.means2d.dtype, proj.means2d.device
    grad_on = torch.is_grad_enabled()
    visible = torch.nonzero(proj.radii > 0).squeeze(1)
    order = visible[torch.argsort(proj.depths.detach()[visible], stable=True)]
    m2d, con, op = proj.means2d[order], proj.conic_ldl[order], proj.opacities[order]
    col, dep = proj.colors[order], proj.depths[order]
    with torch.no_grad():
        r = proj.radii[order].to(torch.float64)
        mx, my = m2d[:, 0].detach().to(torch.float64), m2d[:, 1].detach().to(torch.float64)
        lo_x, hi_x, lo_y, hi_y = mx - r, mx + r, my - r, my + r

    color_rows, trans_rows, depth_rows = [], [], []
    n_fragments = 0
    for y0 in range(0, height, tile):
        y1 = min(y0 + tile, height)
        c_row, t_row, d_row = [], [], []
        for x0 in range(0, width, tile):
            x1 = min(x0 + tile, width)
            hit = torch.nonzero((hi_x >= x0) & (lo_x <= x1) & (hi_y >= y0) & (lo_y <= y1)).squeeze(1)
            args = (m2d[hit], con[hit], op[hit], col[hit], dep[hit], x0, x1, y0, y1, dtype, device)
            # under autograd, keep only the tile's inputs and recompute its pixels x splats
            # tensors in backward, so memory stays one tile's worth however large the image
            c, t, d, n = (checkpoint(_composite_tile, *args, use_reentrant=False) if grad_on
                          else _composite_tile(*args))
            c_row.append(c)
            t_row.append(t)
            d_row.append(d)
            n_fragments += int(n)
        color_rows.append(torch.cat(c_row, 1))
        trans_rows.append(torch.cat(t_row, 1))
        depth_rows.append(torch.cat(d_row, 1))
    return torch.cat(color_rows, 0), torch.cat(trans_rows, 0), torch.cat(depth_rows, 0), n_fragments


def _composite_tile(m2d, con, op, col, dep, x0, x1, y0, y1, dtype, device):
    """Dense compositing of G depth-sorted splats over one (y1-y0) x (x1-x0) pixel tile."""
    h, w = y1 - y0, x1 - x0
    if m2d.shape[0] == 0:
        # keep the graph connected so callers can always backward
        zero = (m2d.sum() + con.sum() + op.sum() + col.sum() + dep.sum()) * 0.0
        return (torch.zeros(h, w, 3, dtype=dtype, device=device) + zero,
                torch.ones(h, w, dtype=dtype, device=device) + zero,
                torch.zeros(h, w, dtype=dtype, device=device) + zero, torch.zeros((), dtype=torch.int64))
    px = (torch.arange(x0, x1, dtype=dtype, device=device) + 0.5).repeat(h)
    py = (torch.arange(y0, y1, dtype=dtype, device=device) + 0.5).repeat_interleave(w)
    dx = px[:, None] - m2d[None, :, 0]  # (P, G)
    dy = py[:, None] - m2d[None, :, 1]
    a, r, q = con[None, :, 0], con[None, :, 1], con[None, :, 2]
    e = dx + r * dy
    power = 0.5 * (a * e * e + q * dy * dy)
    alpha = torch.clamp(op[None, :] * torch.exp(-power), max=ALPHA_MAX)
    candidate = (power <= POWER_MAX) & (alpha >= ALPHA_MIN)
    one = torch.ones((), dtype=dtype, device=device)
    with torch.no_grad():
        t_after = torch.cumprod(torch.where(candidate, 1.0 - alpha, one), dim=1)
        blended = candidate & (t_after >= T_MIN)
    a_b = torch.where(blended, alpha, torch.zeros((), dtype=dtype, device=device))
    t_incl = torch.cumprod(1.0 - a_b, dim=1)
    t_excl = torch.cat([torch.ones_like(t_incl[:, :1]), t_incl[:, :-1]], 1)
    weights = a_b * t_excl
    color = weights @ col
    depth = weights @ dep
    return color.reshape(h, w, 3), t_incl[:, -1].reshape(h, w), depth.reshape(h, w), blended.sum()
