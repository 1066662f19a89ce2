"""The plane sweep's matching cost as one fused numba kernel.

Same function as the torch version (``plane_scores_torch`` in fixer4d/init/matching_cost.py, the
readable reference): per plane and reference tile, every source view warped through the
plane-induced homography (bilinear, ``grid_sample(align_corners=False, padding_mode="zeros")``
semantics, a sample outside the source image is 0), windowed ZNCC against the reference (box
means that shrink at the tile border, a window with less than MVS_MIN_INSIDE of its samples
inside the source scores -1), the mean of the best k sources, and a box aggregation. Why: the
torch version is ~25 small ops per (source, chunk of planes), and the coarse-to-fine sweep calls
it on 16-pixel tiles, so on Panoptic (320x180, 5 init frames) Python and op dispatch took most
of the 4.6 s of plane sweeps and two worker threads ran no faster than one (they take turns
holding the GIL). Here one call covers every (plane, tile) pair of a batch, parallel over the
pairs, without the GIL.

float32 arithmetic like the torch version, in a different order (box sums as running sums of
the window rows): scores agree to ~1e-5 (tests/init/test_mvs_kernel.py).
"""
from __future__ import annotations

import numpy as np

from fixer4d.jit import NUMBA_ERROR, njit, prange


def unavailable_reason() -> str | None:
    """None when the kernel can run, else why not."""
    return NUMBA_ERROR


if njit is not None:

    @njit(cache=True)
    def _box_mean(src, k, tmp, out):
        """out = mean of src (h, w) over a k x k window shrinking at the borders (no padding);
        tmp: (h, w) scratch. Sums of shifted rows (inner loops over x vectorize), then one
        multiply by the per-pixel reciprocal tap count, as the torch ``_box``."""
        h, w = src.shape
        r = k // 2
        for y in range(h):
            for x in range(w):
                tmp[y, x] = src[y, x]
            for i in range(1, min(r, w - 1) + 1):
                for x in range(w - i):
                    tmp[y, x] += src[y, x + i]
                for x in range(i, w):
                    tmp[y, x] += src[y, x - i]
        for y in range(h):
            for x in range(w):
                out[y, x] = tmp[y, x]
            for i in range(1, r + 1):
                if y + i < h:
                    for x in range(w):
                        out[y, x] += tmp[y + i, x]
                if y - i >= 0:
                    for x in range(w):
                        out[y, x] += tmp[y - i, x]
            cy = min(y, r) + min(h - 1 - y, r) + 1
            for x in range(w):
                cx = min(x, r) + min(w - 1 - x, r) + 1
                out[y, x] *= np.float32(1.0) / np.float32(cy * cx)

    @njit(cache=True, parallel=True, error_model="numpy")
    def zncc_scores(ref, ref_mu, ref_var, srcs, src_size, A, bvec, ws, window, aggregation, topk, eps,
                    min_inside, out):
        """Aggregated top-k ZNCC of B reference tiles on n planes.

        ref, ref_mu, ref_var: (B, h, w) float32 reference tiles and their windowed mean/variance.
        srcs: (S, Hmax, Wmax) float32 source grays (each in its top-left corner); src_size: (S, 2)
        int64 (height, width). A: (S, 3, B h w) float32, bvec: (S, 3) float32: source pixel
        ~ A p + w b at inverse depth w. ws: (n, Bw) float32 inverse depths, Bw = B or 1 (the
        same planes for every tile). out: (n, B, h, w) float32.
        """
        n = ws.shape[0]
        B, h, w = ref.shape
        S = srcs.shape[0]
        hw = h * w
        f32 = np.float32
        one, half, two = f32(1.0), f32(0.5), f32(2.0)
        for job in prange(n * B):
            i, bt = job // B, job % B
            wv = ws[i, bt if ws.shape[1] > 1 else 0]
            zs = np.empty((S, h, w), np.float32)
            warped = np.empty((h, w), np.float32)
            maps = np.empty((4, h, w), np.float32)
            means = np.empty((4, h, w), np.float32)
            tmp = np.empty((h, w), np.float32)
            for s in range(S):
                Hs, Ws = src_size[s, 0], src_size[s, 1]
                fW, fH = f32(Ws), f32(Hs)
                nx, ny = two / fW, two / fH  # the reference's normalization scale, then back
                b0, b1, b2 = bvec[s, 0], bvec[s, 1], bvec[s, 2]
                n_inside = 0
                for y in range(h):
                    for x in range(w):
                        p = bt * hw + y * w + x
                        z = A[s, 2, p] + wv * b2
                        u = (A[s, 0, p] + wv * b0) / z
                        v = (A[s, 1, p] + wv * b1) / z
                        val = f32(0.0)
                        ins = f32(0.0)
                        if z > 0 and u >= 0 and u <= fW and v >= 0 and v <= fH:
                            ins = one
                            n_inside += 1
                            # grid_sample(align_corners=False): pixel i's centre at u = i + 0.5;
                            # normalized to [-1, 1] and back as the reference does (same rounding)
                            ix = ((u * nx - one + one) * fW - one) * half
                            iy = ((v * ny - one + one) * fH - one) * half
                            fx0 = np.floor(ix)
                            fy0 = np.floor(iy)
                            tx = ix - fx0
                            ty = iy - fy0
                            x0 = int(fx0)
                            y0 = int(fy0)
                            # corners outside the image weigh 0 (zeros padding): clamped reads
                            ok_x0 = f32(x0 >= 0)
                            ok_x1 = f32(x0 + 1 < Ws)
                            ok_y0 = f32(y0 >= 0)
                            ok_y1 = f32(y0 + 1 < Hs)
                            xa, xb = max(x0, 0), min(x0 + 1, Ws - 1)
                            ya, yb = max(y0, 0), min(y0 + 1, Hs - 1)
                            top = (one - tx) * ok_x0 * srcs[s, ya, xa] + tx * ok_x1 * srcs[s, ya, xb]
                            bot = (one - tx) * ok_x0 * srcs[s, yb, xa] + tx * ok_x1 * srcs[s, yb, xb]
                            val = (one - ty) * ok_y0 * top + ty * ok_y1 * bot
                        warped[y, x] = val
                        maps[0, y, x] = val
                        maps[1, y, x] = val * val
                        maps[2, y, x] = val * ref[bt, y, x]
                        maps[3, y, x] = ins
                # every sample inside: the inside share is 1 everywhere, no need to filter it
                for m in range(3 if n_inside == hw else 4):
                    _box_mean(maps[m], window, tmp, means[m])
                for y in range(h):
                    for x in range(w):
                        mu_s = means[0, y, x]
                        var_s = max(means[1, y, x] - mu_s * mu_s, f32(0.0))
                        cross = means[2, y, x] - mu_s * ref_mu[bt, y, x]
                        zn = cross / np.sqrt(var_s * ref_var[bt, y, x] + eps)
                        if n_inside < hw and means[3, y, x] < min_inside:
                            zn = f32(-1.0)
                        zs[s, y, x] = zn
            # mean of the best k sources per pixel (insertion sort of the S values, descending)
            score = warped  # reuse the buffer
            vals = np.empty(S, np.float32)
            inv_k = one / f32(topk)
            for y in range(h):
                for x in range(w):
                    for s in range(S):
                        val = zs[s, y, x]
                        j = s
                        while j > 0 and vals[j - 1] < val:
                            vals[j] = vals[j - 1]
                            j -= 1
                        vals[j] = val
                    acc = f32(0.0)
                    for s in range(topk):
                        acc += vals[s]
                    score[y, x] = acc * inv_k
            if aggregation > 1:
                _box_mean(score, aggregation, tmp, out[i, bt])
            else:
                out[i, bt] = score
