"""The fast CPU rasterizer: numba kernels with a hand-written backward.

Same splats and the same blending rule as the oracle (fixer4d/render/reference.py), in float32:

* binning (serial, O(tile-splat pairs)): visible splats are depth-sorted once (stable), then
  appended in that order to the flat index list of every TILE x TILE tile that their box
  touches, so each tile's list comes out sorted without a per-tile sort. The box is the radius
  box cut to the bounding box of the ellipse where the splat can still reach alpha >= ALPHA_MIN
  (power <= ln(opacity / ALPHA_MIN), with a safety margin): only provably non-blending pixels
  are left out, so results do not change; at opacity 0.1 the lists are ~25 % shorter.
* forward (parallel over tiles): a tile's splats are packed contiguously (structure of arrays),
  then walked front to back one splat at a time over the tile's 64 pixel lanes, restricted to
  the rows of the splat's box. Each lane follows exactly the sequential per-pixel rule (same
  float32 operations in the same order, early stop included); the lane loop is branch-free
  with exp(-power) in explicit arithmetic (_exp_neg, correctly rounded), so LLVM vectorizes
  it. It stores the final transmittance and, per pixel, the list position of its last blended
  splat.
* backward (parallel over tiles): the reverse walk (as in 3DGS/gsplat), lane-parallel the same
  way, recovering the transmittance before each splat as T / (1 - alpha); per-splat gradients
  dL/d(mean2d, conic, opacity, colour, depth) are summed over the lanes and accumulated in one
  float64 buffer per chunk of tiles (no atomics); the buffers are summed at the end.
* scheduling: tiles are ordered by work and dealt evenly to the threads (static schedule).

Memory is the image, the projected splats and the flat tile lists. Chain rule from the 2D splats
to means/quats/scales is torch autograd through fixer4d/render/project.py.
"""
from __future__ import annotations

import contextlib
import math

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
_ZERO = np.float32(0.0)
_TILE = C.TILE
_LANES = C.TILE * C.TILE  # one lane per pixel of a tile (the lane reductions assume 64)
# per-splat gradient slots in the accumulation buffers
_G_MX, _G_MY, _G_A, _G_B, _G_C, _G_O, _G_R, _G_G, _G_BL, _G_Z = range(10)
_N_GRAD = 10
# rows of a tile's packed splats
_S_MX, _S_MY, _S_A, _S_B, _S_C, _S_O, _S_R, _S_G, _S_BL, _S_Z = range(10)
_N_SP = 10
# slots (of _LANES floats each) of the backward's flat lane state, then the _N_GRAD contributions.
# Unsigned: numba skips the negative-index wraparound for unsigned indices, which would otherwise
# keep LLVM from vectorizing the lane loops.
(_BU_PX, _BU_PY, _BU_T, _BU_TF, _BU_CNT, _BU_GR, _BU_GG, _BU_GB, _BU_GD, _BU_GT, _BU_RR, _BU_RG, _BU_RB,
 _BU_RD) = (np.uint64(k) for k in range(14))
_B_C0 = 14
_B_SLOTS = _B_C0 + _N_GRAD
_B_C0_U = np.uint64(_B_C0)
_LANES_U = np.uint64(_LANES)
_U1, _U2, _U3, _U4, _U5, _U6, _U7, _U8, _U16, _U32 = (np.uint64(k) for k in (1, 2, 3, 4, 5, 6, 7, 8, 16, 32))
# exp(-power) in explicit float64 arithmetic (see _exp_neg): power is clamped to this (the
# result is used only for power <= POWER_MAX = 4.5), so 2^n needs n >= -9 only
_F64 = np.float64
_EXP_CLAMP = np.float32(6.0)
_LOG2E = 1.4426950408889634
_LN2 = 0.6931471805599453
_ROUND_MAGIC = 6755399441055744.0  # 1.5 * 2^52: (x + M) - M rounds x to an integer
# Taylor coefficients 1/k!, k = 10..0: on |r| <= ln2/2 the truncation error is < 1e-11, far
# below half a float32 ulp, so rounding the float64 result gives the correctly rounded expf
_E10, _E9, _E8, _E7, _E6, _E5, _E4, _E3, _E2, _E1, _E0 = (1.0 / math.factorial(k) for k in range(10, -1, -1))
# binning: float64 thresholds and the safety margins of the opacity-aware ellipse box
_POWER_MAX64 = float(C.POWER_MAX)
_ALPHA_MIN64 = float(np.float32(C.ALPHA_MIN))
_BOX_REL_MARGIN = 1e-3  # relative, far above float32 round-off of power (~1e-6)
_BOX_ABS_MARGIN = 1e-2  # pixels, far above float32 round-off of a pixel coordinate


def unavailable_reason() -> str | None:
    """None when the numba kernels can run, else why not."""
    return _IMPORT_ERROR


if numba is not None:

    @njit(inline="always")
    def _exp_neg(power):
        """exp(-power) as float32, correctly rounded (float64 Horner after range reduction).

        Explicit arithmetic (no libm call) so that the per-pixel loops vectorize; callers use
        the result only where power <= POWER_MAX, so the argument is clamped to [.., 6]. Agrees
        bit-for-bit with libm's expf on >99.9 % of float32 inputs in [0, 6] (max 0.5 ulp).
        """
        x = -_F64(min(power, _EXP_CLAMP))
        n = (x * _LOG2E + _ROUND_MAGIC) - _ROUND_MAGIC  # round to nearest integer
        r = x - n * _LN2
        p = ((((((((((_E10 * r + _E9) * r + _E8) * r + _E7) * r + _E6) * r + _E5) * r + _E4) * r
                 + _E3) * r + _E2) * r + _E1) * r + _E0)
        # times 2^n, n in [-9, 0], by exact power-of-two factors (selects, no bit casts)
        m = -n
        b = m >= 8.0
        s = 0.00390625 if b else 1.0
        m = m - 8.0 if b else m
        b = m >= 4.0
        s = s * 0.0625 if b else s
        m = m - 4.0 if b else m
        b = m >= 2.0
        s = s * 0.25 if b else s
        m = m - 2.0 if b else m
        s = s * 0.5 if m >= 1.0 else s
        return np.float32(p * s)

    @njit(cache=True)
    def _bin_tiles(mx, my, ca, cb, cc, op, radii, order, width, height, tile):
        """Flat per-tile lists of splat ids, each in the depth order of ``order``.

        Returns (offsets (n_tiles + 1,) int64, ids (pairs,) int32, rows (N, 2) int32: the first
        and last pixel row of each binned splat's box, used to skip a tile's rows it cannot
        reach). A splat goes to every tile
        holding a pixel whose centre may blend it: inside both its radius box (one pixel of
        slack against round-off) and the bounding box of the ellipse power <= min(POWER_MAX,
        ln(opacity / ALPHA_MIN)) (beyond it alpha < ALPHA_MIN), widened by a safety margin.
        Only pixels that provably cannot blend the splat are left out, so results are the same
        as with the radius box alone; the per-pixel tests decide exactly.
        """
        n_tx = (width + tile - 1) // tile
        n_ty = (height + tile - 1) // tile
        counts = np.zeros(n_tx * n_ty + 1, np.int64)
        ranges = np.empty((order.shape[0], 4), np.int64)
        rows = np.zeros((mx.shape[0], 2), np.int32)
        for k in range(order.shape[0]):
            g = order[k]
            r = float(radii[g])
            x = float(mx[g])
            y = float(my[g])
            rx = r
            ry = r
            a, rr, q = float(ca[g]), float(cb[g]), float(cc[g])
            level = min(_POWER_MAX64, np.log(float(op[g]) / _ALPHA_MIN64))
            if a > 0.0 and q > 0.0:
                level = level * (1.0 + _BOX_REL_MARGIN) + _BOX_REL_MARGIN
                # half-extents of {d : 0.5 d^T conic d <= level} are sqrt(2 level Sigma_xx), ...;
                # from the LDL form Sigma_xx = r^2 / q + 1 / a, Sigma_yy = 1 / q (no cancellation)
                ex = np.sqrt(2.0 * level * (rr * rr / q + 1.0 / a)) * (1.0 + _BOX_REL_MARGIN) + _BOX_ABS_MARGIN
                ey = np.sqrt(2.0 * level / q) * (1.0 + _BOX_REL_MARGIN) + _BOX_ABS_MARGIN
                if np.isfinite(ex) and ex < rx:
                    rx = ex
                if np.isfinite(ey) and ey < ry:
                    ry = ey
            # pixel u is covered when u + 0.5 is in [x - r, x + r]
            u0 = max(np.floor(x - rx - 0.5), 0.0)
            u1 = min(np.ceil(x + rx - 0.5), width - 1.0)
            v0 = max(np.floor(y - ry - 0.5), 0.0)
            v1 = min(np.ceil(y + ry - 0.5), height - 1.0)
            if u0 > u1 or v0 > v1:
                ranges[k, 0] = 1
                ranges[k, 1] = 0
                ranges[k, 2] = 1
                ranges[k, 3] = 0
                continue
            rows[g, 0] = int(v0)
            rows[g, 1] = int(v1)
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
        return offsets, ids, rows

    @njit(cache=True)
    def _pack_tile(mx, my, ca, cb, cc, op, col, z, ids, start, n):
        """The tile's splats, contiguous in list order: (10, n) float32 rows _S_*."""
        sp = np.empty((_N_SP, n), np.float32)
        for i in range(n):
            g = ids[start + i]
            sp[_S_MX, i] = mx[g]
            sp[_S_MY, i] = my[g]
            sp[_S_A, i] = ca[g]
            sp[_S_B, i] = cb[g]
            sp[_S_C, i] = cc[g]
            sp[_S_O, i] = op[g]
            sp[_S_R, i] = col[g, 0]
            sp[_S_G, i] = col[g, 1]
            sp[_S_BL, i] = col[g, 2]
            sp[_S_Z, i] = z[g]
        return sp

    @njit(cache=True)
    def _forward_tile(sp, n, ids, start, rows, x0, y0, width, height, out_color, out_trans, out_depth,
                      out_count):
        """Front-to-back compositing of one tile, splat by splat over the tile's pixel lanes.

        Each lane (pixel) follows exactly the sequential rule of the oracle (same float32
        operations in the same order per pixel); the loop over lanes is branch-free so LLVM
        vectorizes it. Returns the number of blended fragments.
        """
        px = np.empty(_LANES, np.float32)
        py = np.empty(_LANES, np.float32)
        tr = np.ones(_LANES, np.float32)
        cr = np.zeros(_LANES, np.float32)
        cg = np.zeros(_LANES, np.float32)
        cbl = np.zeros(_LANES, np.float32)
        cd = np.zeros(_LANES, np.float32)
        walked = np.zeros(_LANES, np.float32)
        live = np.zeros(_LANES, np.int32)
        nbl = np.zeros(_LANES, np.int32)
        for p in range(_LANES):
            u = x0 + p % _TILE
            v = y0 + p // _TILE
            px[p] = np.float32(u) + _HALF
            py[p] = np.float32(v) + _HALF
            if u < width and v < height:
                live[p] = 1
        n_live = 1
        for i in range(n):
            if (i & 15) == 0:  # stop the tile once every pixel has terminated
                n_live = 0
                for p in range(_LANES):
                    n_live += live[p]
                if n_live == 0:
                    break
            smx, smy = sp[_S_MX, i], sp[_S_MY, i]
            a, r, q, o = sp[_S_A, i], sp[_S_B, i], sp[_S_C, i], sp[_S_O, i]
            sr, sg, sb, sz = sp[_S_R, i], sp[_S_G, i], sp[_S_BL, i], sp[_S_Z, i]
            fi = np.float32(i + 1)
            g = ids[start + i]
            # only the tile rows inside the splat's box (the others cannot blend it)
            p0 = max(rows[g, 0] - y0, 0) * _TILE
            p1 = (min(rows[g, 1] - y0, _TILE - 1) + 1) * _TILE
            for pi in range(p0, p1):
                p = np.uint64(pi)  # unsigned: no negative-index wraparound, so LLVM vectorizes
                dx = px[p] - smx
                dy = py[p] - smy
                e = dx + r * dy
                power = _HALF * (a * e * e + q * dy * dy)
                alpha = o * _exp_neg(power)
                alpha = _ALPHA_MAX if alpha > _ALPHA_MAX else alpha
                t = tr[p]
                t_next = t * (_ONE - alpha)
                ok = (power <= _POWER_MAX) & (alpha >= _ALPHA_MIN) & (live[p] != 0)
                blend = ok & (t_next >= _T_MIN)
                w = alpha * t
                cr[p] = cr[p] + w * sr if blend else cr[p]
                cg[p] = cg[p] + w * sg if blend else cg[p]
                cbl[p] = cbl[p] + w * sb if blend else cbl[p]
                cd[p] = cd[p] + w * sz if blend else cd[p]
                tr[p] = t_next if blend else t
                walked[p] = fi if blend else walked[p]
                nbl[p] += 1 if blend else 0
                live[p] = 0 if (ok & (t_next < _T_MIN)) else live[p]
        nf = 0
        for p in range(_LANES):
            u = x0 + p % _TILE
            v = y0 + p // _TILE
            if u < width and v < height:
                out_color[v, u, 0] = cr[p]
                out_color[v, u, 1] = cg[p]
                out_color[v, u, 2] = cbl[p]
                out_depth[v, u] = cd[p]
                out_trans[v, u] = tr[p]
                out_count[v, u] = np.int32(walked[p])
                nf += nbl[p]
        return nf

    @njit(parallel=True, cache=True)
    def _forward(mx, my, ca, cb, cc, op, col, z, offsets, ids, rows, tile_perm, width, height,
                 out_color, out_trans, out_depth, out_count):
        """Front-to-back compositing, parallel over tiles; returns blended fragments per tile."""
        n_tx = (width + _TILE - 1) // _TILE
        n_tiles = tile_perm.shape[0]
        frags = np.zeros(n_tiles, np.int64)
        for k in prange(n_tiles):
            t = tile_perm[k]
            start = offsets[t]
            n = offsets[t + 1] - start
            sp = _pack_tile(mx, my, ca, cb, cc, op, col, z, ids, start, n)
            frags[k] = _forward_tile(sp, n, ids, start, rows, (t % n_tx) * _TILE, (t // n_tx) * _TILE,
                                     width, height, out_color, out_trans, out_depth, out_count)
        return frags

    @njit(cache=True, error_model="numpy")
    def _backward_tile(sp, n, ids, start, rows, x0, y0, width, height, trans, count, g_color, g_trans,
                       g_depth, out):
        """Reverse walk over one tile (as in 3DGS/gsplat), splat by splat over pixel lanes.

        Per lane, the same float32 recurrences as the sequential walk: the transmittance before
        a splat is recovered as T / (1 - alpha), and rec_* hold the colour/depth of everything
        behind it. Per-splat gradients are summed over the lanes by a pairwise tree and added
        into ``out`` (N, 10) float64. All lane state lives in one flat array at constant
        offsets, so LLVM can prove the lane loop free of aliasing and vectorize it.
        """
        L = _LANES_U
        st = np.zeros(_B_SLOTS * _LANES, np.float32)
        max_cnt = 0
        for pi in range(_LANES):
            p = np.uint64(pi)
            u = x0 + pi % _TILE
            v = y0 + pi // _TILE
            st[_BU_PX * L + p] = np.float32(u) + _HALF
            st[_BU_PY * L + p] = np.float32(v) + _HALF
            st[_BU_T * L + p] = _ONE
            st[_BU_TF * L + p] = _ONE
            if u < width and v < height:
                st[_BU_T * L + p] = trans[v, u]
                st[_BU_TF * L + p] = trans[v, u]
                st[_BU_CNT * L + p] = np.float32(count[v, u])
                st[_BU_GR * L + p] = g_color[v, u, 0]
                st[_BU_GG * L + p] = g_color[v, u, 1]
                st[_BU_GB * L + p] = g_color[v, u, 2]
                st[_BU_GD * L + p] = g_depth[v, u]
                st[_BU_GT * L + p] = g_trans[v, u]
                max_cnt = max(max_cnt, count[v, u])
        for i in range(max_cnt - 1, -1, -1):
            smx, smy = sp[_S_MX, i], sp[_S_MY, i]
            a, r, q, o = sp[_S_A, i], sp[_S_B, i], sp[_S_C, i], sp[_S_O, i]
            sr, sg, sb, sz = sp[_S_R, i], sp[_S_G, i], sp[_S_BL, i], sp[_S_Z, i]
            fi = np.float32(i)
            g = ids[start + i]
            p0 = max(rows[g, 0] - y0, 0) * _TILE
            p1 = (min(rows[g, 1] - y0, _TILE - 1) + 1) * _TILE
            if p1 <= p0:
                continue
            for j in range(_N_GRAD):  # lanes outside the splat's rows contribute nothing
                for pi in range(_LANES):
                    st[(_B_C0_U + np.uint64(j)) * L + np.uint64(pi)] = _ZERO
            for pi in range(p0, p1):
                p = np.uint64(pi)
                dx = st[_BU_PX * L + p] - smx
                dy = st[_BU_PY * L + p] - smy
                e = dx + r * dy
                power = _HALF * (a * e * e + q * dy * dy)
                gauss = _exp_neg(power)
                raw = o * gauss
                alpha = _ALPHA_MAX if raw > _ALPHA_MAX else raw
                valid = (fi < st[_BU_CNT * L + p]) & (power <= _POWER_MAX) & (alpha >= _ALPHA_MIN)
                one_minus = _ONE - alpha
                t0 = st[_BU_T * L + p]
                t = t0 / one_minus
                w = alpha * t
                r0, r1 = st[_BU_RR * L + p], st[_BU_RG * L + p]
                r2, r3 = st[_BU_RB * L + p], st[_BU_RD * L + p]
                g0, g1 = st[_BU_GR * L + p], st[_BU_GG * L + p]
                g2, g3 = st[_BU_GB * L + p], st[_BU_GD * L + p]
                g_alpha = (t * ((sr - r0) * g0 + (sg - r1) * g1 + (sb - r2) * g2 + (sz - r3) * g3)
                           - st[_BU_TF * L + p] / one_minus * st[_BU_GT * L + p])
                st[_BU_T * L + p] = t if valid else t0
                st[_BU_RR * L + p] = alpha * sr + one_minus * r0 if valid else r0
                st[_BU_RG * L + p] = alpha * sg + one_minus * r1 if valid else r1
                st[_BU_RB * L + p] = alpha * sb + one_minus * r2 if valid else r2
                st[_BU_RD * L + p] = alpha * sz + one_minus * r3 if valid else r3
                free = valid & (raw <= _ALPHA_MAX)  # clamped alpha ignores opacity and conic
                g_power = -raw * g_alpha
                st[(_B_C0_U + np.uint64(_G_R)) * L + p] = w * g0 if valid else _ZERO
                st[(_B_C0_U + np.uint64(_G_G)) * L + p] = w * g1 if valid else _ZERO
                st[(_B_C0_U + np.uint64(_G_BL)) * L + p] = w * g2 if valid else _ZERO
                st[(_B_C0_U + np.uint64(_G_Z)) * L + p] = w * g3 if valid else _ZERO
                st[(_B_C0_U + np.uint64(_G_O)) * L + p] = gauss * g_alpha if free else _ZERO
                ae = a * e
                st[(_B_C0_U + np.uint64(_G_MX)) * L + p] = -(g_power * ae) if free else _ZERO
                st[(_B_C0_U + np.uint64(_G_MY)) * L + p] = -(g_power * (ae * r + q * dy)) if free else _ZERO
                st[(_B_C0_U + np.uint64(_G_A)) * L + p] = g_power * _HALF * e * e if free else _ZERO
                st[(_B_C0_U + np.uint64(_G_B)) * L + p] = g_power * ae * dy if free else _ZERO
                st[(_B_C0_U + np.uint64(_G_C)) * L + p] = g_power * _HALF * dy * dy if free else _ZERO
            # pairwise sum over the lanes: constant-length elementwise halvings (vectorized)
            for j in range(_N_GRAD):
                base = (_B_C0_U + np.uint64(j)) * L
                for qi in range(32):
                    q = np.uint64(qi)
                    st[base + q] += st[base + q + _U32]
                for qi in range(16):
                    q = np.uint64(qi)
                    st[base + q] += st[base + q + _U16]
                for qi in range(8):
                    q = np.uint64(qi)
                    st[base + q] += st[base + q + _U8]
            for j in range(_N_GRAD):
                base = (_B_C0_U + np.uint64(j)) * L
                out[g, j] += ((st[base] + st[base + _U4]) + (st[base + _U1] + st[base + _U5])) + (
                    (st[base + _U2] + st[base + _U6]) + (st[base + _U3] + st[base + _U7]))

    @njit(parallel=True, cache=True)
    def _backward(mx, my, ca, cb, cc, op, col, z, offsets, ids, rows, tile_order, width, height,
                  trans, count, g_color, g_trans, g_depth, n_splats, n_chunks):
        """Reverse walk per tile; returns per-chunk gradient sums (n_chunks, N, 10) float64.

        Chunk c owns tiles tile_order[c::n_chunks] (tile_order by decreasing work, so the
        chunks get equal shares) and its own buffer: no two threads ever add into the same
        memory, and the sums do not depend on thread timing.
        """
        n_tx = (width + _TILE - 1) // _TILE
        n_tiles = tile_order.shape[0]
        out = np.zeros((n_chunks, n_splats, _N_GRAD), np.float64)
        for chunk in prange(n_chunks):
            for k in range(chunk, n_tiles, n_chunks):
                t = tile_order[k]
                start = offsets[t]
                n = offsets[t + 1] - start
                if n > 0:
                    sp = _pack_tile(mx, my, ca, cb, cc, op, col, z, ids, start, n)
                    _backward_tile(sp, n, ids, start, rows, (t % n_tx) * _TILE, (t // n_tx) * _TILE,
                                   width, height, trans, count, g_color, g_trans, g_depth, out[chunk])
        return out


def _tile_orders(offsets: np.ndarray, n_threads: int) -> tuple[np.ndarray, np.ndarray]:
    """(by_work, dealt): tiles by decreasing work (list length, stable), and the same dealt
    round-robin into n_threads contiguous blocks. prange's static schedule gives thread c the
    c-th contiguous block of ``dealt`` (the forward), the backward's chunk c takes
    by_work[c::n_threads]: either way every thread gets an equal share of heavy and light
    tiles, without the per-tile dispatch cost of a dynamic schedule (measured 3x slower)."""
    by_work = np.argsort(-np.diff(offsets), kind="stable").astype(np.int64)
    dealt = np.concatenate([by_work[c::n_threads] for c in range(n_threads)])
    return by_work, dealt


@contextlib.contextmanager
def _torch_threads_kept():
    """Run numba's parallel machinery without letting it change torch's intra-op thread count.

    numba's "omp" threading layer and torch share one libgomp (same soname), and numba's first
    use of its thread pool (a parallel kernel, or even numba.get_num_threads()) sets the OpenMP
    thread count to every core, silently raising ``torch.get_num_threads()`` from what the
    caller chose (e.g. 1) to 2. Under load every small torch op then pays a two-thread OpenMP
    barrier: a training iteration measured 1.9 s instead of 0.3 s (30k Gaussians, 320x180), and
    a 50k fwd+bwd render 4.3 s instead of 0.45 s. The count is restored on exit.
    """
    n = torch.get_num_threads()
    try:
        yield
    finally:
        if torch.get_num_threads() != n:
            torch.set_num_threads(n)


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
        offsets, ids, rows = _bin_tiles(mx, my, ca, cb, cc, op, radii_np, order, width, height, _TILE)
        color = np.empty((height, width, 3), np.float32)
        trans = np.empty((height, width), np.float32)
        depth = np.empty((height, width), np.float32)
        count = np.empty((height, width), np.int32)
        with _torch_threads_kept():
            by_work, dealt = _tile_orders(offsets, numba.get_num_threads())
            frags = _forward(mx, my, ca, cb, cc, op, col, z, offsets, ids, rows, dealt, width, height,
                             color, trans, depth, count)
        ctx.arrays = (mx, my, ca, cb, cc, op, col, z, offsets, ids, rows, by_work, trans, count)
        ctx.size = (width, height)
        n_frag = torch.tensor(int(frags.sum()), dtype=torch.int64)
        ctx.mark_non_differentiable(n_frag)
        dev = means2d.device
        return (torch.from_numpy(color).to(dev), torch.from_numpy(trans).to(dev),
                torch.from_numpy(depth).to(dev), n_frag)

    @staticmethod
    def backward(ctx, g_color, g_trans, g_depth, _g_frag):
        mx, my, ca, cb, cc, op, col, z, offsets, ids, rows, by_work, trans, count = ctx.arrays
        width, height = ctx.size

        def grad_np(g, shape):
            return np.zeros(shape, np.float32) if g is None else _as_np(g)

        with _torch_threads_kept():
            sums = _backward(mx, my, ca, cb, cc, op, col, z, offsets, ids, rows, by_work, width, height,
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
        proj.means2d.to(f32), proj.conic_ldl.to(f32), proj.opacities.to(f32), proj.colors.to(f32),
        proj.depths.to(f32), proj.radii, int(width), int(height))
    return color, trans, depth, int(n_frag)
