"""The fast CPU rasterizer: numba kernels with a hand-written backward.

Same splats and the same blending rule as the oracle (fixer4d/render/reference.py), in float32:

* binning (serial, O(tile-splat pairs)): visible splats are depth-sorted once (stable), then
  appended in that order to the flat index list of every TILE x TILE tile their 3-sigma box
  touches, so each tile's list comes out sorted without a per-tile sort;
* forward (parallel over tiles): per pixel, a front-to-back walk over its tile's list with the
  early stop; it stores the final transmittance and how many list entries it walked;
* backward (parallel over tiles): per pixel, the reverse walk over the same entries (as in
  3DGS/gsplat), recovering the transmittance before each splat as T / (1 - alpha) and
  accumulating dL/d(mean2d, conic, opacity, colour, depth) per tile, then into one buffer per
  chunk of tiles (one chunk per thread, no atomics); the buffers are summed at the end.

Memory is the image, the projected splats and the flat tile lists. Chain rule from the 2D splats
to means/quats/scales is torch autograd through fixer4d/render/project.py.
"""
from __future__ import annotations

import numpy as np
import torch

from fixer4d.render import constants as C
from fixer4d.render.project import Projection

try:  # numba is a core dependency, but "auto" must still work (via the oracle) without it
    import numba
    from numba import njit, prange
except ImportError as _exc:  # pragma: no cover - exercised only on broken installs
    numba = None
    _IMPORT_ERROR = f"numba is not importable ({_exc}); install numba or use backend='reference'"
else:
    _IMPORT_ERROR = None

# float32 copies of the thresholds: numba would promote a float32 compared with a Python float
# to float64, while torch compares float32 tensors with scalars in float32. Using float32
# constants makes every threshold decision bit-identical to the oracle's in float32.
_HALF = np.float32(0.5)
_ONE = np.float32(1.0)
_POWER_MAX = np.float32(C.POWER_MAX)
_ALPHA_MAX = np.float32(C.ALPHA_MAX)
_ALPHA_MIN = np.float32(C.ALPHA_MIN)
_T_MIN = np.float32(C.T_MIN)
_TILE = C.TILE
# per-splat gradient slots in the accumulation buffers
_G_MX, _G_MY, _G_A, _G_B, _G_C, _G_O, _G_R, _G_G, _G_BL, _G_Z = range(10)
_N_GRAD = 10


def unavailable_reason() -> str | None:
    """None when the numba kernels can run, else why not."""
    return _IMPORT_ERROR


if numba is not None:

    @njit(cache=True)
    def _bin_tiles(mx, my, radii, order, width, height, tile):
        """Flat per-tile lists of splat ids, each in the depth order of ``order``.

        Returns (offsets (n_tiles + 1,) int64, ids (pairs,) int32). A splat goes to every tile
        holding a pixel whose centre lies within its radius box (one pixel of slack against
        round-off; the per-pixel 3-sigma test decides exactly).
        """
        n_tx = (width + tile - 1) // tile
        n_ty = (height + tile - 1) // tile
        counts = np.zeros(n_tx * n_ty + 1, np.int64)
        ranges = np.empty((order.shape[0], 4), np.int64)
        for k in range(order.shape[0]):
            g = order[k]
            r = float(radii[g])
            x = float(mx[g])
            y = float(my[g])
            # pixel u is covered when u + 0.5 is in [x - r, x + r]
            u0 = max(np.floor(x - r - 0.5), 0.0)
            u1 = min(np.ceil(x + r - 0.5), width - 1.0)
            v0 = max(np.floor(y - r - 0.5), 0.0)
            v1 = min(np.ceil(y + r - 0.5), height - 1.0)
            if u0 > u1 or v0 > v1:
                ranges[k, 0] = 1
                ranges[k, 1] = 0
                ranges[k, 2] = 1
                ranges[k, 3] = 0
                continue
            tx0, tx1 = int(u0) // tile, int(u1) // tile
            ty0, ty1 = int(v0) // tile, int(v1) // tile
            ranges[k, 0] = tx0
            ranges[k, 1] = tx1
            ranges[k, 2] = ty0
            ranges[k, 3] = ty1
            for ty in range(ty0, ty1 + 1):
                for tx in range(tx0, tx1 + 1):
                    counts[ty * n_tx + tx + 1] += 1
        offsets = np.cumsum(counts)
        ids = np.empty(offsets[-1], np.int32)
        cursor = offsets[:-1].copy()
        for k in range(order.shape[0]):
            g = order[k]
            for ty in range(ranges[k, 2], ranges[k, 3] + 1):
                for tx in range(ranges[k, 0], ranges[k, 1] + 1):
                    t = ty * n_tx + tx
                    ids[cursor[t]] = g
                    cursor[t] += 1
        return offsets, ids

    @njit(parallel=True, cache=True, fastmath=False)
    def _forward(mx, my, ca, cb, cc, op, col, z, offsets, ids, tile_perm, width, height, tile,
                 out_color, out_trans, out_depth, out_count):
        """Front-to-back compositing; returns the number of blended fragments per tile."""
        n_tx = (width + tile - 1) // tile
        n_tiles = tile_perm.shape[0]
        frags = np.zeros(n_tiles, np.int64)
        for k in prange(n_tiles):
            t = tile_perm[k]
            x0 = (t % n_tx) * tile
            y0 = (t // n_tx) * tile
            start = offsets[t]
            n = offsets[t + 1] - start
            lmx = np.empty(n, np.float32)
            lmy = np.empty(n, np.float32)
            la = np.empty(n, np.float32)
            lb = np.empty(n, np.float32)
            lc = np.empty(n, np.float32)
            lo = np.empty(n, np.float32)
            lcol = np.empty((n, 3), np.float32)
            lz = np.empty(n, np.float32)
            for i in range(n):
                g = ids[start + i]
                lmx[i] = mx[g]
                lmy[i] = my[g]
                la[i] = ca[g]
                lb[i] = cb[g]
                lc[i] = cc[g]
                lo[i] = op[g]
                lcol[i, 0] = col[g, 0]
                lcol[i, 1] = col[g, 1]
                lcol[i, 2] = col[g, 2]
                lz[i] = z[g]
            nf = 0
            for v in range(y0, min(y0 + tile, height)):
                py = np.float32(v) + _HALF
                for u in range(x0, min(x0 + tile, width)):
                    px = np.float32(u) + _HALF
                    T = _ONE
                    r = np.float32(0.0)
                    gg = np.float32(0.0)
                    bb = np.float32(0.0)
                    d = np.float32(0.0)
                    walked = 0
                    for i in range(n):
                        dx = px - lmx[i]
                        dy = py - lmy[i]
                        power = _HALF * (la[i] * dx * dx + lc[i] * dy * dy) + lb[i] * dx * dy
                        if power > _POWER_MAX:
                            continue
                        alpha = lo[i] * np.float32(np.exp(-power))
                        if alpha > _ALPHA_MAX:
                            alpha = _ALPHA_MAX
                        if alpha < _ALPHA_MIN:
                            continue
                        t_next = T * (_ONE - alpha)
                        if t_next < _T_MIN:
                            break
                        w = alpha * T
                        r += w * lcol[i, 0]
                        gg += w * lcol[i, 1]
                        bb += w * lcol[i, 2]
                        d += w * lz[i]
                        T = t_next
                        walked = i + 1
                        nf += 1
                    out_color[v, u, 0] = r
                    out_color[v, u, 1] = gg
                    out_color[v, u, 2] = bb
                    out_depth[v, u] = d
                    out_trans[v, u] = T
                    out_count[v, u] = walked
            frags[k] = nf
        return frags

    @njit(cache=True, fastmath=False)
    def _backward_tile(mx, my, ca, cb, cc, op, col, z, ids, start, n, x0, y0, width, height, tile,
                       trans, count, g_color, g_trans, g_depth, out):
        """Reverse walk over one tile's pixels; adds the tile's gradients into ``out`` (N, 10)."""
        acc = np.zeros((n, _N_GRAD), np.float64)
        # the tile's splats packed contiguously (the walk reads them once per pixel)
        lmx = np.empty(n, np.float32)
        lmy = np.empty(n, np.float32)
        la = np.empty(n, np.float32)
        lb = np.empty(n, np.float32)
        lc = np.empty(n, np.float32)
        lo = np.empty(n, np.float32)
        lcol = np.empty((n, 4), np.float32)
        for i in range(n):
            g = ids[start + i]
            lmx[i] = mx[g]
            lmy[i] = my[g]
            la[i] = ca[g]
            lb[i] = cb[g]
            lc[i] = cc[g]
            lo[i] = op[g]
            lcol[i, 0] = col[g, 0]
            lcol[i, 1] = col[g, 1]
            lcol[i, 2] = col[g, 2]
            lcol[i, 3] = z[g]
        for v in range(y0, min(y0 + tile, height)):
            py = np.float32(v) + _HALF
            for u in range(x0, min(x0 + tile, width)):
                px = np.float32(u) + _HALF
                t_final = trans[v, u]
                T = t_final
                gr, gg, gb = g_color[v, u, 0], g_color[v, u, 1], g_color[v, u, 2]
                gd = g_depth[v, u]
                gt = g_trans[v, u]
                # colour and depth of everything behind splat i, as seen through the splats
                # between (3DGS's accum_rec)
                rec_r = np.float32(0.0)
                rec_g = np.float32(0.0)
                rec_b = np.float32(0.0)
                rec_d = np.float32(0.0)
                for i in range(count[v, u] - 1, -1, -1):
                    dx = px - lmx[i]
                    dy = py - lmy[i]
                    a, b, c = la[i], lb[i], lc[i]
                    power = _HALF * (a * dx * dx + c * dy * dy) + b * dx * dy
                    if power > _POWER_MAX:
                        continue
                    gauss = np.float32(np.exp(-power))
                    raw = lo[i] * gauss
                    alpha = raw
                    if alpha > _ALPHA_MAX:
                        alpha = _ALPHA_MAX
                    if alpha < _ALPHA_MIN:
                        continue
                    one_minus = _ONE - alpha
                    T = T / one_minus
                    w = alpha * T
                    cr, cg, cbl, cz = lcol[i, 0], lcol[i, 1], lcol[i, 2], lcol[i, 3]
                    acc[i, _G_R] += w * gr
                    acc[i, _G_G] += w * gg
                    acc[i, _G_BL] += w * gb
                    acc[i, _G_Z] += w * gd
                    g_alpha = (T * ((cr - rec_r) * gr + (cg - rec_g) * gg + (cbl - rec_b) * gb
                                    + (cz - rec_d) * gd) - t_final / one_minus * gt)
                    rec_r = alpha * cr + one_minus * rec_r
                    rec_g = alpha * cg + one_minus * rec_g
                    rec_b = alpha * cbl + one_minus * rec_b
                    rec_d = alpha * cz + one_minus * rec_d
                    if raw > _ALPHA_MAX:
                        continue  # clamped: alpha does not depend on opacity or the conic
                    acc[i, _G_O] += gauss * g_alpha
                    g_power = -raw * g_alpha
                    acc[i, _G_MX] -= g_power * (a * dx + b * dy)
                    acc[i, _G_MY] -= g_power * (b * dx + c * dy)
                    acc[i, _G_A] += g_power * 0.5 * dx * dx
                    acc[i, _G_B] += g_power * dx * dy
                    acc[i, _G_C] += g_power * 0.5 * dy * dy
        for i in range(n):
            g = ids[start + i]
            for j in range(_N_GRAD):
                out[g, j] += acc[i, j]

    @njit(parallel=True, cache=True, fastmath=False)
    def _backward(mx, my, ca, cb, cc, op, col, z, offsets, ids, tile_perm, width, height, tile,
                  trans, count, g_color, g_trans, g_depth, n_splats, n_chunks):
        """Reverse walk per pixel; returns per-chunk gradient sums (n_chunks, N, 10) float64.

        Chunk c owns tiles tile_perm[c::n_chunks] and its own buffer, so no two threads ever
        add into the same memory.
        """
        n_tx = (width + tile - 1) // tile
        n_tiles = tile_perm.shape[0]
        out = np.zeros((n_chunks, n_splats, _N_GRAD), np.float64)
        for chunk in prange(n_chunks):
            for k in range(chunk, n_tiles, n_chunks):
                t = tile_perm[k]
                start = offsets[t]
                n = offsets[t + 1] - start
                if n > 0:
                    _backward_tile(mx, my, ca, cb, cc, op, col, z, ids, start, n, (t % n_tx) * tile,
                                   (t // n_tx) * tile, width, height, tile, trans, count, g_color,
                                   g_trans, g_depth, out[chunk])
        return out


def _tile_permutation(n_tiles: int) -> np.ndarray:
    """A fixed pseudo-random order of tiles: prange hands each thread a contiguous chunk of it,
    so busy and empty image regions are spread evenly over the threads."""
    return np.random.default_rng(0).permutation(n_tiles).astype(np.int64)


def _as_np(t: torch.Tensor) -> np.ndarray:
    return np.ascontiguousarray(t.detach().to(torch.float32).cpu().numpy())


class _RasterizeCPU(torch.autograd.Function):
    @staticmethod
    def forward(ctx, means2d, conics, opacities, colors, depths, radii, width, height):
        mx, my = _as_np(means2d[:, 0]), _as_np(means2d[:, 1])
        ca, cb, cc = _as_np(conics[:, 0]), _as_np(conics[:, 1]), _as_np(conics[:, 2])
        op, col, z = _as_np(opacities), _as_np(colors), _as_np(depths)
        radii_np = radii.detach().cpu().numpy().astype(np.int64)
        # alpha <= opacity, so a splat below ALPHA_MIN opacity never blends: not binned
        visible = np.nonzero((radii_np > 0) & (op >= _ALPHA_MIN))[0]
        order = visible[np.argsort(z[visible], kind="stable")].astype(np.int64)
        offsets, ids = _bin_tiles(mx, my, radii_np, order, width, height, _TILE)
        perm = _tile_permutation(offsets.shape[0] - 1)
        color = np.empty((height, width, 3), np.float32)
        trans = np.empty((height, width), np.float32)
        depth = np.empty((height, width), np.float32)
        count = np.empty((height, width), np.int32)
        frags = _forward(mx, my, ca, cb, cc, op, col, z, offsets, ids, perm, width, height, _TILE,
                         color, trans, depth, count)
        ctx.arrays = (mx, my, ca, cb, cc, op, col, z, offsets, ids, perm, trans, count)
        ctx.size = (width, height)
        n_frag = torch.tensor(int(frags.sum()), dtype=torch.int64)
        ctx.mark_non_differentiable(n_frag)
        dev = means2d.device
        return (torch.from_numpy(color).to(dev), torch.from_numpy(trans).to(dev),
                torch.from_numpy(depth).to(dev), n_frag)

    @staticmethod
    def backward(ctx, g_color, g_trans, g_depth, _g_frag):
        mx, my, ca, cb, cc, op, col, z, offsets, ids, perm, trans, count = ctx.arrays
        width, height = ctx.size

        def grad_np(g, shape):
            return np.zeros(shape, np.float32) if g is None else _as_np(g)

        sums = _backward(mx, my, ca, cb, cc, op, col, z, offsets, ids, perm, width, height, _TILE,
                         trans, count, grad_np(g_color, (height, width, 3)), grad_np(g_trans, (height, width)),
                         grad_np(g_depth, (height, width)), mx.shape[0], numba.get_num_threads()).sum(0)
        g = torch.from_numpy(sums.astype(np.float32))
        return (g[:, _G_MX:_G_MY + 1], g[:, _G_A:_G_C + 1], g[:, _G_O], g[:, _G_R:_G_BL + 1], g[:, _G_Z],
                None, None, None)


def rasterize_cpu(proj: Projection, width: int, height: int) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, int]:
    """Same contract as ``rasterize_reference``, float32: (color_acc (H, W, 3), transmittance
    (H, W), depth_acc (H, W), n_fragments); differentiable through the hand-written backward."""
    if _IMPORT_ERROR is not None:
        from fixer4d.errors import BackendUnavailable

        raise BackendUnavailable(_IMPORT_ERROR)
    f32 = torch.float32
    color, trans, depth, n_frag = _RasterizeCPU.apply(
        proj.means2d.to(f32), proj.conics.to(f32), proj.opacities.to(f32), proj.colors.to(f32),
        proj.depths.to(f32), proj.radii, int(width), int(height))
    return color, trans, depth, int(n_frag)
