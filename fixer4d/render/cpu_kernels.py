"""The numba kernels of the fast CPU rasterizer (fixer4d/render/cpu.py is their torch side).

Same splats and the same blending rule as the oracle (fixer4d/render/reference.py), in float32:

* records: each splat's mean, conic (LDL form, project.stable_conic), opacity, colour and depth
  in one 64-byte float32 row (columns ``R_*``), so a tile fetches a splat with one cache miss.
* binning (``bin_tiles``, O(tile-splat pairs)): visible splats come depth-sorted (stable), and
  are appended in that order to the flat index list of every TILE x TILE tile that their box
  touches, so each tile's list comes out sorted without a per-tile sort. The box is the radius
  box cut to the bounding box of the ellipse where the splat can still reach alpha >= ALPHA_MIN
  (power <= ln(opacity / ALPHA_MIN), with a safety margin): only provably non-blending pixels
  are left out, so results do not change. The widened level and the box's rows go into the
  record for the kernels' row test.
* row test (_active_rows, vectorized over a tile's 8 rows): per (tile, splat), the rows whose
  line cuts the ellipse within the tile's columns and whose gate is open (forward: some pixel
  still live; backward: some pixel blended this far down its list). Only those rows are walked:
  on random-init scenes this removes 35-60 % of the pixel evaluations (lanes outside the
  ellipse and lanes already stopped).
* forward (``composite_forward``, parallel over tiles): walked front to back one splat at a time
  over each maximal run of active rows, 8 pixel lanes at a time. Each lane follows exactly the
  sequential per-pixel rule (same float32 operations in the same order, early stop included);
  the lane loop is branch-free with exp(-power) in explicit float32 arithmetic (_exp_neg,
  < 1 ulp), so LLVM vectorizes it. It stores the final transmittance and, per pixel, the list
  position of its last blended splat.
* backward (``composite_backward``, parallel over tiles): the reverse walk (as in 3DGS/gsplat)
  over the same row runs, recovering the transmittance before each splat as T / (1 - alpha)
  (one reciprocal per lane); per-splat gradients dL/d(mean2d, conic, opacity, colour, depth)
  (slots ``G_*``) are summed over the run's lanes (vectorized sums, _add_lane_sums) and
  accumulated in one float64 buffer per chunk of tiles (no atomics); the buffers are summed at
  the end.
* scheduling: the caller orders tiles by work and deals them evenly to the threads (static
  schedule).

Kernels are defined only when numba imports (``fixer4d.jit``); the constants always are.
"""
from __future__ import annotations

import numpy as np

from fixer4d.jit import njit, numba, prange
import fixer4d.render.constants as C

# float32 copies of the thresholds: numba would promote a float32 compared with a Python float
# to float64, while torch compares float32 tensors with scalars in float32. Using float32
# constants makes every threshold decision bit-identical to the oracle's in float32.
_HALF = np.float32(0.5)
_ONE = np.float32(1.0)
_POWER_MAX = np.float32(C.POWER_MAX)
_ALPHA_MAX = np.float32(C.ALPHA_MAX)
ALPHA_MIN32 = np.float32(C.ALPHA_MIN)
_T_MIN = np.float32(C.T_MIN)
_ZERO = np.float32(0.0)
_TILE = C.TILE
_LANES = C.TILE * C.TILE  # one lane per pixel of a tile (the lane reductions assume 64)
# per-splat gradient slots in the accumulation buffers
G_MX, G_MY, G_A, G_B, G_C, G_O, G_R, G_G, G_BL, G_Z = range(10)
N_GRAD = 10
# columns of the (N, R_N) float32 splat records: one 64-byte row per splat, so a tile reads a
# splat with one cache miss. Mean (px), conic in LDL form (a, r, q), opacity, colour, depth,
# then what binning adds: the widened power level of the opacity-aware ellipse and the first and
# last pixel row of its box (integers, exact in float32).
(R_MX, R_MY, R_A, R_R, R_Q, R_O, R_CR, R_CG, R_CB, R_Z, R_LEV, R_ROW0, R_ROW1) = range(13)
R_N = 16
# Slots (of _LANES floats each) of the kernels' flat lane state: one array at constant offsets,
# so LLVM can prove the lane loops free of aliasing. Unsigned: numba skips the negative-index
# wraparound for unsigned indices, which would otherwise keep LLVM from vectorizing the loops.
(_FU_PX, _FU_PY, _FU_T, _FU_CR, _FU_CG, _FU_CB, _FU_CD, _FU_WALK, _FU_NBL, _FU_LIVE) = (
    np.uint64(k) for k in range(10))
_F_SLOTS = 10
# the backward's lane state, then the N_GRAD per-lane gradient contributions of the current splat
(_BU_PX, _BU_PY, _BU_T, _BU_CNT, _BU_GR, _BU_GG, _BU_GB, _BU_GD, _BU_TG, _BU_RR, _BU_RG, _BU_RB,
 _BU_RD) = (np.uint64(k) for k in range(13))
(_GU_MX, _GU_MY, _GU_A, _GU_B, _GU_C, _GU_O, _GU_R, _GU_G, _GU_BL, _GU_Z) = (np.uint64(13 + k) for k in range(10))
_B_SLOTS = 13 + 10
_RECOUNT_MASK = 7  # the forward recounts its live rows every 8 splats
_GATE_OPEN = np.float32(2 ** 30)  # a forward row gate above every list position
_LANES_U = np.uint64(_LANES)
# exp(-power) in explicit float32 arithmetic (see _exp_neg): power is clamped to this (the
# result is used only for power <= POWER_MAX = 4.5), so 2^n needs n >= -9 only
_EXP_CLAMP = np.float32(6.0)
_LOG2E = np.float32(1.4426950408889634)
_ROUND_MAGIC = np.float32(12582912.0)  # 1.5 * 2^23: (x + M) - M rounds a float32 x to an integer
# Cody-Waite split of ln 2: _LN2_HI has 9 significant bits, so n * _LN2_HI is exact for |n| <= 9
# and r = x - n ln2 keeps float32 accuracy
_LN2_HI = np.float32(0.693359375)
_LN2_LO = np.float32(-2.12194440e-4)
# Cephes expf: exp(r) = 1 + r + r^2 P(r) on |r| <= ln2 / 2 (degree-5 P, minimax)
_EP5, _EP4, _EP3, _EP2, _EP1, _EP0 = (np.float32(v) for v in (
    1.9875691500e-4, 1.3981999507e-3, 8.3334519073e-3, 4.1665795894e-2, 1.6666665459e-1, 5.0000001201e-1))
# measured bound of _exp_neg (exhaustively, every float32 power in [0, 6]; tests/render/
# test_cpu_kernel.py checks it on a dense sample): max error in units of the last place
EXP_MAX_ULP = 0.99
# binning: float64 thresholds and the safety margins of the opacity-aware ellipse box
_POWER_MAX64 = float(C.POWER_MAX)
_ALPHA_MIN64 = float(np.float32(C.ALPHA_MIN))
_BOX_REL_MARGIN = 1e-3  # relative, far above float32 round-off of power (~1e-6)
_BOX_ABS_MARGIN = 1e-2  # pixels, far above float32 round-off of a pixel coordinate
# per-row ellipse test (_active_rows): absolute pixels, and relative to the offsets the float32
# per-pixel test subtracts (its round-off is ~6e-8 of them)
_ROW_ABS_MARGIN = 1e-2
_ROW_REL_MARGIN = 1e-5
_ROW_REL2 = (1.0 + _BOX_REL_MARGIN) ** 2  # the relative margin of the half-width, squared
_ROW_HALF_SPAN = 0.5 * C.TILE - 0.5  # from a tile row's middle to its outer pixel centres
# binning: chunks of the depth order per thread (see bin_tiles); 4 evens out the near/far
# imbalance while the per-chunk tile counters stay small (chunks x tiles int64)
_BIN_CHUNKS_PER_THREAD = 4


if numba is not None:

    @njit(inline="always")
    def _exp_neg(power):
        """exp(-power) in float32 arithmetic: Cody-Waite range reduction, Cephes' polynomial and
        an exact scaling by 2^n (selects, no bit casts, no libm call: the lane loops vectorize
        with 8 float32 lanes per AVX register).

        Error: at most 0.98 ulp, measured over every float32 power in [0, 6] (1.09e9 inputs);
        99.4 % of the results equal the correctly rounded value (torch's float32 exp, which the
        oracle uses: 98.9 %). Callers use the result only where power <= POWER_MAX, so the
        argument is clamped to [.., 6] (2^n with n >= -9).
        """
        x = -min(power, _EXP_CLAMP)
        n = (x * _LOG2E + _ROUND_MAGIC) - _ROUND_MAGIC  # round to nearest integer
        r = (x - n * _LN2_HI) - n * _LN2_LO
        p = (((((_EP5 * r + _EP4) * r + _EP3) * r + _EP2) * r + _EP1) * r + _EP0) * (r * r) + r + _ONE
        # times 2^n, n in [-9, 0], by exact power-of-two factors
        m = -n
        b = m >= np.float32(8.0)
        s = np.float32(0.00390625) if b else _ONE
        m = m - np.float32(8.0) if b else m
        b = m >= np.float32(4.0)
        s = s * np.float32(0.0625) if b else s
        m = m - np.float32(4.0) if b else m
        b = m >= np.float32(2.0)
        s = s * np.float32(0.25) if b else s
        m = m - np.float32(2.0) if b else m
        s = s * _HALF if m >= _ONE else s
        return p * s

    @njit(cache=True)
    def _bin_box(rec, radii, g, width, height, tile, out):
        """Tile range of splat g -> out[0:4] = (tx0, tx1, ty0, ty1) (empty: tx0 > tx1); fills
        its record's R_LEV, R_ROW0 and R_ROW1 (see bin_tiles)."""
        r = float(radii[g])
        x = float(rec[g, R_MX])
        y = float(rec[g, R_MY])
        rx = r
        ry = r
        a, rr, q = float(rec[g, R_A]), float(rec[g, R_R]), float(rec[g, R_Q])
        level = min(_POWER_MAX64, np.log(float(rec[g, R_O]) / _ALPHA_MIN64))
        level = level * (1.0 + _BOX_REL_MARGIN) + _BOX_REL_MARGIN
        rec[g, R_LEV] = np.float32(level * (1.0 + _BOX_REL_MARGIN))  # rounding up, generously
        if a > 0.0 and q > 0.0:
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
            out[0] = 1
            out[1] = 0
            out[2] = 1
            out[3] = 0
            return
        rec[g, R_ROW0] = np.float32(v0)  # exact: image rows are far below 2^24
        rec[g, R_ROW1] = np.float32(v1)
        out[0] = int(u0) // tile
        out[1] = int(u1) // tile
        out[2] = int(v0) // tile
        out[3] = int(v1) // tile

    @njit(cache=True, parallel=True)
    def bin_tiles(rec, radii, order, width, height, tile, n_threads):
        """Flat per-tile lists of splat ids, each in the depth order of ``order``.

        rec: (N, R_N) float32 splat records (see _records); this fills their R_LEV, R_ROW0
        and R_ROW1 slots for the binned splats. Returns (offsets (n_tiles + 1,) int64, ids
        (pairs,) int32). A splat goes to every tile holding a pixel whose centre may blend it:
        inside both its radius box (one pixel of slack against round-off) and the bounding box
        of the ellipse power <= level = min(POWER_MAX, ln(opacity / ALPHA_MIN)) (beyond it
        alpha < ALPHA_MIN), widened by a safety margin. Only pixels that provably cannot blend
        the splat are left out, so results are the same as with the radius box alone; the
        per-pixel tests decide exactly. R_LEV keeps the widened level (the kernels' per-row
        test), R_ROW0/R_ROW1 the first and last pixel row of the box.

        Parallel over contiguous chunks of ``order``: each chunk counts its tile pairs, chunk c
        writes after chunks 0..c-1 in every tile, so each list keeps the order of ``order`` and
        the result does not depend on the thread count. _BIN_CHUNKS_PER_THREAD chunks per
        thread, dealt round-robin (prange's static schedule gives thread i the i-th contiguous
        block of ``dealt``): near splats (early in the order) cover more tiles, so one chunk per
        thread would leave the first thread most of the work.
        """
        n_tx = (width + tile - 1) // tile
        n_ty = (height + tile - 1) // tile
        n_tiles = n_tx * n_ty
        n = order.shape[0]
        n_threads = max(1, n_threads)
        n_chunks = max(1, min(n_threads * _BIN_CHUNKS_PER_THREAD, n))
        bounds = np.linspace(0, n, n_chunks + 1).astype(np.int64)
        dealt = np.empty(n_chunks, np.int64)
        i = 0
        for th in range(n_threads):
            for c in range(th, n_chunks, n_threads):
                dealt[i] = c
                i += 1
        counts = np.zeros((n_chunks, n_tiles), np.int64)
        ranges = np.empty((n, 4), np.int64)
        for i in prange(n_chunks):
            c = dealt[i]
            for k in range(bounds[c], bounds[c + 1]):
                _bin_box(rec, radii, order[k], width, height, tile, ranges[k])
                for ty in range(ranges[k, 2], ranges[k, 3] + 1):
                    for tx in range(ranges[k, 0], ranges[k, 1] + 1):
                        counts[c, ty * n_tx + tx] += 1
        offsets = np.zeros(n_tiles + 1, np.int64)
        cursor = np.empty((n_chunks, n_tiles), np.int64)
        total = 0
        for t in range(n_tiles):
            offsets[t] = total
            for c in range(n_chunks):
                cursor[c, t] = total
                total += counts[c, t]
        offsets[n_tiles] = total
        ids = np.empty(total, np.int32)
        for i in prange(n_chunks):
            c = dealt[i]
            for k in range(bounds[c], bounds[c + 1]):
                g = order[k]
                for ty in range(ranges[k, 2], ranges[k, 3] + 1):
                    for tx in range(ranges[k, 0], ranges[k, 1] + 1):
                        t = ty * n_tx + tx
                        ids[cursor[c, t]] = g
                        cursor[c, t] += 1
        return offsets, ids

    @njit(inline="always")
    def _active_rows(rec, g, fi, x0, y0, n_rows, row_gate, act):
        """Marks in act[0:TILE] the tile rows the splat may blend; returns how many.

        A row is active when it lies in the splat's box, its gate is open (row_gate[row] > fi:
        some pixel of the row can still blend list position fi), and the row's line cuts the
        ellipse power <= R_LEV in an interval that reaches the row's pixel centres x0 + 0.5 ..
        x0 + TILE - 0.5, widened by margins far above the float32 round-off of the per-pixel
        test (_ROW_* constants; float64 here). The interval's half-width is sqrt(s / a) with
        s = 2 level - q dy^2 (LDL form), compared squared: no sqrt or division per row.
        """
        smx, smy = float(rec[g, R_MX]), float(rec[g, R_MY])
        a, rr, q = float(rec[g, R_A]), float(rec[g, R_R]), float(rec[g, R_Q])
        lev2 = 2.0 * float(rec[g, R_LEV])
        v0, v1 = float(rec[g, R_ROW0]), float(rec[g, R_ROW1])
        x_mid = float(x0) + 0.5 * _TILE
        n_act = 0
        for row in range(n_rows):
            v = float(y0 + row)
            dy = v + 0.5 - smy
            s = lev2 - q * dy * dy
            rdy = rr * dy
            xc = smx - rdy
            d = abs(xc - x_mid) - _ROW_HALF_SPAN - (_ROW_ABS_MARGIN + _ROW_REL_MARGIN * (abs(xc) + abs(rdy)))
            d = max(d, 0.0)
            ok = (s >= 0.0) & (a * d * d <= s * _ROW_REL2) & (v >= v0) & (v <= v1) & (row_gate[row] > fi)
            act[row] = ok
            n_act += 1 if ok else 0
        return n_act

    @njit(cache=True, error_model="numpy")
    def _forward_tile(rec, ids, start, n, x0, y0, width, height, out_color, out_trans, out_depth, out_count):
        """Front-to-back compositing of one tile, splat by splat over the tile's pixel lanes.

        Each lane (pixel) follows exactly the sequential rule of the oracle (same float32
        operations in the same order per pixel); the lane loop is branch-free so LLVM
        vectorizes it. Per splat it runs over each maximal run of consecutive active rows
        (_active_rows: a row is skipped when all its pixels have stopped or when the splat's
        ellipse misses it); the tile stops once every pixel has. Returns the number of blended
        fragments.
        """
        L = _LANES_U
        st = np.zeros(_F_SLOTS * _LANES, np.float32)
        row_gate = np.zeros(_TILE, np.float32)  # 2^30 while a row has a live pixel, else 0
        act = np.zeros(_TILE, np.bool_)
        n_rows = min(_TILE, height - y0)  # rows inside the image (a runtime bound: see _active_rows)
        for pi in range(_LANES):
            p = np.uint64(pi)
            u = x0 + pi % _TILE
            v = y0 + pi // _TILE
            st[_FU_PX * L + p] = np.float32(u) + _HALF
            st[_FU_PY * L + p] = np.float32(v) + _HALF
            st[_FU_T * L + p] = _ONE
            if u < width and v < height:
                st[_FU_LIVE * L + p] = _ONE
                row_gate[pi // _TILE] = _GATE_OPEN
        for i in range(n):
            if (i & _RECOUNT_MASK) == 0:  # close the rows whose pixels have all stopped
                n_live_rows = 0
                for row in range(_TILE):
                    n_row = 0
                    for l in range(_TILE):
                        n_row += 1 if st[_FU_LIVE * L + np.uint64(row * _TILE + l)] != _ZERO else 0
                    row_gate[row] = _GATE_OPEN if n_row > 0 else _ZERO
                    n_live_rows += 1 if n_row > 0 else 0
                if n_live_rows == 0:
                    break
            g = ids[start + i]
            if _active_rows(rec, g, _ZERO, x0, y0, n_rows, row_gate, act) == 0:
                continue
            smx, smy = rec[g, R_MX], rec[g, R_MY]
            a, r, q, o = rec[g, R_A], rec[g, R_R], rec[g, R_Q], rec[g, R_O]
            sr, sg, sb, sz = rec[g, R_CR], rec[g, R_CG], rec[g, R_CB], rec[g, R_Z]
            fi = np.float32(i + 1)
            row = 0
            while row < n_rows:
                if not act[row]:
                    row += 1
                    continue
                ra = row
                while row + 1 < n_rows and act[row + 1]:
                    row += 1
                for pi in range(ra * _TILE, (row + 1) * _TILE):
                    p = np.uint64(pi)  # unsigned: no negative-index wraparound, so LLVM vectorizes
                    dx = st[_FU_PX * L + p] - smx
                    dy = st[_FU_PY * L + p] - smy
                    e = dx + r * dy
                    power = _HALF * (a * e * e + q * dy * dy)
                    alpha = o * _exp_neg(power)
                    alpha = _ALPHA_MAX if alpha > _ALPHA_MAX else alpha
                    t = st[_FU_T * L + p]
                    t_next = t * (_ONE - alpha)
                    live = st[_FU_LIVE * L + p]
                    ok = (power <= _POWER_MAX) & (alpha >= ALPHA_MIN32) & (live != _ZERO)
                    blend = ok & (t_next >= _T_MIN)
                    w = alpha * t
                    st[_FU_CR * L + p] = st[_FU_CR * L + p] + w * sr if blend else st[_FU_CR * L + p]
                    st[_FU_CG * L + p] = st[_FU_CG * L + p] + w * sg if blend else st[_FU_CG * L + p]
                    st[_FU_CB * L + p] = st[_FU_CB * L + p] + w * sb if blend else st[_FU_CB * L + p]
                    st[_FU_CD * L + p] = st[_FU_CD * L + p] + w * sz if blend else st[_FU_CD * L + p]
                    st[_FU_T * L + p] = t_next if blend else t
                    st[_FU_WALK * L + p] = fi if blend else st[_FU_WALK * L + p]
                    st[_FU_NBL * L + p] += _ONE if blend else _ZERO
                    st[_FU_LIVE * L + p] = _ZERO if (ok & (t_next < _T_MIN)) else live
                row += 1
        nf = 0
        for pi in range(_LANES):
            p = np.uint64(pi)
            u = x0 + pi % _TILE
            v = y0 + pi // _TILE
            if u < width and v < height:
                out_color[v, u, 0] = st[_FU_CR * L + p]
                out_color[v, u, 1] = st[_FU_CG * L + p]
                out_color[v, u, 2] = st[_FU_CB * L + p]
                out_depth[v, u] = st[_FU_CD * L + p]
                out_trans[v, u] = st[_FU_T * L + p]
                out_count[v, u] = np.int32(st[_FU_WALK * L + p])
                nf += int(st[_FU_NBL * L + p])
        return nf

    @njit(parallel=True, cache=True)
    def composite_forward(rec, offsets, ids, tile_perm, width, height, out_color, out_trans, out_depth, out_count):
        """Front-to-back compositing, parallel over tiles; returns blended fragments per tile."""
        n_tx = (width + _TILE - 1) // _TILE
        n_tiles = tile_perm.shape[0]
        frags = np.zeros(n_tiles, np.int64)
        for k in prange(n_tiles):
            t = tile_perm[k]
            start = offsets[t]
            frags[k] = _forward_tile(rec, ids, start, offsets[t + 1] - start, (t % n_tx) * _TILE,
                                     (t // n_tx) * _TILE, width, height, out_color, out_trans, out_depth, out_count)
        return frags

    @njit(cache=True, fastmath={"reassoc"})
    def _add_lane_sums(st, lo, hi, out, g):
        """out[g, j] += the sum of the backward's per-lane contributions j over lanes lo..hi-1.

        Reassociation is allowed here only, so that LLVM vectorizes these sums (a strict
        left-to-right float sum cannot be); the order is still fixed by the code, so results do
        not depend on timing."""
        L = _LANES_U
        s0 = s1 = s2 = s3 = s4 = s5 = s6 = s7 = s8 = s9 = _ZERO
        for p in range(lo, hi):  # one pass, ten running sums (vectorized as ten lane vectors)
            s0 += st[_GU_MX * L + p]
            s1 += st[_GU_MY * L + p]
            s2 += st[_GU_A * L + p]
            s3 += st[_GU_B * L + p]
            s4 += st[_GU_C * L + p]
            s5 += st[_GU_O * L + p]
            s6 += st[_GU_R * L + p]
            s7 += st[_GU_G * L + p]
            s8 += st[_GU_BL * L + p]
            s9 += st[_GU_Z * L + p]
        out[g, G_MX] += s0
        out[g, G_MY] += s1
        out[g, G_A] += s2
        out[g, G_B] += s3
        out[g, G_C] += s4
        out[g, G_O] += s5
        out[g, G_R] += s6
        out[g, G_G] += s7
        out[g, G_BL] += s8
        out[g, G_Z] += s9

    @njit(cache=True, error_model="numpy")
    def _backward_tile(rec, ids, start, x0, y0, width, height, trans, count, g_color, g_trans, g_depth, out):
        """Reverse walk over one tile (as in 3DGS/gsplat), splat by splat over pixel lanes.

        Per lane, the same float32 recurrences as the sequential walk: the transmittance before
        a splat is recovered as T / (1 - alpha), and rec_* hold the colour/depth of everything
        behind it. Per splat the lane loop runs over each maximal run of active rows
        (_active_rows: rows where some pixel blended at or beyond this list position and the
        ellipse reaches); the run's per-lane gradient contributions are then summed
        (_add_lane_sums) into ``out`` (N, 10) float64. All lane state lives in one flat array
        at constant offsets, so LLVM can prove the lane loop free of aliasing and vectorize it.
        """
        L = _LANES_U
        st = np.zeros(_B_SLOTS * _LANES, np.float32)
        row_gate = np.zeros(_TILE, np.float32)  # a row's largest count: no blending at or beyond it
        act = np.zeros(_TILE, np.bool_)
        n_rows = min(_TILE, height - y0)  # rows inside the image (a runtime bound: see _active_rows)
        max_cnt = 0
        for pi in range(_LANES):
            p = np.uint64(pi)
            u = x0 + pi % _TILE
            v = y0 + pi // _TILE
            st[_BU_PX * L + p] = np.float32(u) + _HALF
            st[_BU_PY * L + p] = np.float32(v) + _HALF
            st[_BU_T * L + p] = _ONE
            if u < width and v < height:
                st[_BU_T * L + p] = trans[v, u]
                st[_BU_CNT * L + p] = np.float32(count[v, u])
                st[_BU_GR * L + p] = g_color[v, u, 0]
                st[_BU_GG * L + p] = g_color[v, u, 1]
                st[_BU_GB * L + p] = g_color[v, u, 2]
                st[_BU_GD * L + p] = g_depth[v, u]
                # the transmittance term of every splat's alpha gradient: T_final g_T / (1 - alpha)
                st[_BU_TG * L + p] = trans[v, u] * g_trans[v, u]
                max_cnt = max(max_cnt, count[v, u])
                row_gate[pi // _TILE] = max(row_gate[pi // _TILE], np.float32(count[v, u]))
        for i in range(max_cnt - 1, -1, -1):
            g = ids[start + i]
            fi = np.float32(i)
            if _active_rows(rec, g, fi, x0, y0, n_rows, row_gate, act) == 0:
                continue
            smx, smy = rec[g, R_MX], rec[g, R_MY]
            a, r, q, o = rec[g, R_A], rec[g, R_R], rec[g, R_Q], rec[g, R_O]
            sr, sg, sb, sz = rec[g, R_CR], rec[g, R_CG], rec[g, R_CB], rec[g, R_Z]
            row = 0
            while row < n_rows:
                if not act[row]:
                    row += 1
                    continue
                ra = row
                while row + 1 < n_rows and act[row + 1]:
                    row += 1
                for pi in range(ra * _TILE, (row + 1) * _TILE):
                    p = np.uint64(pi)
                    dx = st[_BU_PX * L + p] - smx
                    dy = st[_BU_PY * L + p] - smy
                    e = dx + r * dy
                    power = _HALF * (a * e * e + q * dy * dy)
                    gauss = _exp_neg(power)
                    raw = o * gauss
                    alpha = _ALPHA_MAX if raw > _ALPHA_MAX else raw
                    valid = (fi < st[_BU_CNT * L + p]) & (power <= _POWER_MAX) & (alpha >= ALPHA_MIN32)
                    one_minus = _ONE - alpha
                    inv = _ONE / one_minus
                    t0 = st[_BU_T * L + p]
                    t = t0 * inv
                    w = alpha * t
                    r0, r1 = st[_BU_RR * L + p], st[_BU_RG * L + p]
                    r2, r3 = st[_BU_RB * L + p], st[_BU_RD * L + p]
                    g0, g1 = st[_BU_GR * L + p], st[_BU_GG * L + p]
                    g2, g3 = st[_BU_GB * L + p], st[_BU_GD * L + p]
                    g_alpha = (t * ((sr - r0) * g0 + (sg - r1) * g1 + (sb - r2) * g2 + (sz - r3) * g3)
                               - st[_BU_TG * L + p] * inv)
                    st[_BU_T * L + p] = t if valid else t0
                    st[_BU_RR * L + p] = alpha * sr + one_minus * r0 if valid else r0
                    st[_BU_RG * L + p] = alpha * sg + one_minus * r1 if valid else r1
                    st[_BU_RB * L + p] = alpha * sb + one_minus * r2 if valid else r2
                    st[_BU_RD * L + p] = alpha * sz + one_minus * r3 if valid else r3
                    free = valid & (raw <= _ALPHA_MAX)  # clamped alpha ignores opacity and conic
                    gp = -raw * g_alpha if free else _ZERO
                    wv = w if valid else _ZERO
                    ae = a * e
                    st[_GU_R * L + p] = wv * g0
                    st[_GU_G * L + p] = wv * g1
                    st[_GU_BL * L + p] = wv * g2
                    st[_GU_Z * L + p] = wv * g3
                    st[_GU_O * L + p] = gauss * g_alpha if free else _ZERO
                    st[_GU_MX * L + p] = -(gp * ae)
                    st[_GU_MY * L + p] = -(gp * (ae * r + q * dy))
                    st[_GU_A * L + p] = gp * _HALF * e * e
                    st[_GU_B * L + p] = gp * ae * dy
                    st[_GU_C * L + p] = gp * _HALF * dy * dy
                _add_lane_sums(st, np.uint64(ra * _TILE), np.uint64((row + 1) * _TILE), out, g)
                row += 1

    @njit(parallel=True, cache=True)
    def composite_backward(rec, offsets, ids, tile_order, width, height, trans, count, g_color, g_trans, g_depth,
                           n_chunks):
        """Reverse walk per tile; returns per-chunk gradient sums (n_chunks, N, 10) float64.

        Chunk c owns tiles tile_order[c::n_chunks] (tile_order by decreasing work, so the
        chunks get equal shares) and its own buffer: no two threads ever add into the same
        memory, and the sums do not depend on thread timing.
        """
        n_tx = (width + _TILE - 1) // _TILE
        n_tiles = tile_order.shape[0]
        out = np.zeros((n_chunks, rec.shape[0], N_GRAD), np.float64)
        for chunk in prange(n_chunks):
            for k in range(chunk, n_tiles, n_chunks):
                t = tile_order[k]
                if offsets[t + 1] > offsets[t]:
                    _backward_tile(rec, ids, offsets[t], (t % n_tx) * _TILE, (t // n_tx) * _TILE, width, height,
                                   trans, count, g_color, g_trans, g_depth, out[chunk])
        return out
