// Forward compositing of fixer4d's CPU rasterizer in C++, for the numba-vs-C++ decision
// record (docs/render.md). Reads exactly the binned data of fixer4d/render/cpu.py (per-tile
// depth-sorted id lists, per-splat pixel-row ranges, tile order) and writes the same outputs.
// Built at run time by run.py with g++ -O3 -march=native -fopenmp (no -ffast-math).
//
// forward_lanes: the algorithm of the numba kernel (splat by splat over a tile's 64 pixel
//   lanes, branch-free lane loop, exp(-power) in explicit float64 arithmetic).
// forward_pixel: the previous numba algorithm (per pixel, a sequential walk over the tile's
//   list with libm expf), for scale.
#include <cmath>
#include <cstdint>
#include <cstring>
#include <vector>
#include <omp.h>

namespace {
constexpr int TILE = 8, LANES = 64;
constexpr float HALF = 0.5f, ONE = 1.0f, POWER_MAX = 4.5f, ALPHA_MAX = 0.99f,
                ALPHA_MIN = 1.0f / 255.0f, T_MIN = 1e-4f, EXP_CLAMP = 6.0f;

inline float exp_neg(float power) {  // same arithmetic as cpu._exp_neg
    double x = -(double)(power < EXP_CLAMP ? power : EXP_CLAMP);
    const double M = 6755399441055744.0;
    double n = (x * 1.4426950408889634 + M) - M;
    double r = x - n * 0.6931471805599453;
    double p = 1.0 / 3628800.0;
    p = p * r + 1.0 / 362880.0; p = p * r + 1.0 / 40320.0; p = p * r + 1.0 / 5040.0;
    p = p * r + 1.0 / 720.0; p = p * r + 1.0 / 120.0; p = p * r + 1.0 / 24.0;
    p = p * r + 1.0 / 6.0; p = p * r + 0.5; p = p * r + 1.0; p = p * r + 1.0;
    // 2^n built from its exponent bits (numba uses exact power-of-two selects: same value)
    const int64_t bits = ((int64_t)n + 1023) << 52;
    double s;
    std::memcpy(&s, &bits, sizeof s);
    return (float)(p * s);
}
}  // namespace

extern "C" int64_t forward_lanes(const float* mx, const float* my, const float* ca, const float* cb,
                                 const float* cc, const float* op, const float* col, const float* z,
                                 const int64_t* offsets, const int32_t* ids, const int32_t* rows,
                                 const int64_t* order, int64_t n_tiles, int width, int height,
                                 int n_threads, float* out_color, float* out_trans, float* out_depth,
                                 int32_t* out_count) {
    const int n_tx = (width + TILE - 1) / TILE;
    int64_t total = 0;
#pragma omp parallel for schedule(static) num_threads(n_threads) reduction(+ : total)
    for (int64_t k = 0; k < n_tiles; ++k) {
        const int64_t t = order[k];
        const int x0 = (int)(t % n_tx) * TILE, y0 = (int)(t / n_tx) * TILE;
        const int64_t start = offsets[t], n = offsets[t + 1] - start;
        std::vector<float> sp(10 * n);
        float *smx = &sp[0], *smy = smx + n, *sa = smy + n, *sb = sa + n, *sc = sb + n, *so = sc + n,
              *sr = so + n, *sg = sr + n, *sbl = sg + n, *sz = sbl + n;
        for (int64_t i = 0; i < n; ++i) {
            const int g = ids[start + i];
            smx[i] = mx[g]; smy[i] = my[g]; sa[i] = ca[g]; sb[i] = cb[g]; sc[i] = cc[g]; so[i] = op[g];
            sr[i] = col[3 * g]; sg[i] = col[3 * g + 1]; sbl[i] = col[3 * g + 2]; sz[i] = z[g];
        }
        alignas(64) float px[LANES], py[LANES], tr[LANES], cr[LANES], cg[LANES], cbv[LANES], cd[LANES], walked[LANES];
        alignas(64) int32_t live[LANES], nbl[LANES];
        for (int p = 0; p < LANES; ++p) {
            const int u = x0 + p % TILE, v = y0 + p / TILE;
            px[p] = (float)u + HALF; py[p] = (float)v + HALF;
            tr[p] = ONE; cr[p] = cg[p] = cbv[p] = cd[p] = walked[p] = 0.0f;
            live[p] = (u < width && v < height) ? 1 : 0; nbl[p] = 0;
        }
        for (int64_t i = 0; i < n; ++i) {
            if ((i & 15) == 0) {
                int n_live = 0;
                for (int p = 0; p < LANES; ++p) n_live += live[p];
                if (n_live == 0) break;
            }
            const int g = ids[start + i];
            const int r0 = rows[2 * g] - y0 > 0 ? rows[2 * g] - y0 : 0;
            const int r1 = rows[2 * g + 1] - y0 < TILE - 1 ? rows[2 * g + 1] - y0 : TILE - 1;
            const float mxi = smx[i], myi = smy[i], a = sa[i], b = sb[i], c = sc[i], o = so[i];
            const float r_ = sr[i], g_ = sg[i], b_ = sbl[i], z_ = sz[i], fi = (float)(i + 1);
#pragma omp simd
            for (int p = r0 * TILE; p < (r1 + 1) * TILE; ++p) {
                const float dx = px[p] - mxi, dy = py[p] - myi;
                const float power = HALF * (a * dx * dx + c * dy * dy) + b * dx * dy;
                float alpha = o * exp_neg(power);
                alpha = alpha > ALPHA_MAX ? ALPHA_MAX : alpha;
                const float t = tr[p], t_next = t * (ONE - alpha);
                const bool ok = (power <= POWER_MAX) & (alpha >= ALPHA_MIN) & (live[p] != 0);
                const bool blend = ok & (t_next >= T_MIN);
                const float w = alpha * t;
                // computed unconditionally, then selected: GCC (trapping math on) if-converts
                // only selects of values that are evaluated anyway
                const float ncr = cr[p] + w * r_, ncg = cg[p] + w * g_, ncb = cbv[p] + w * b_, ncd = cd[p] + w * z_;
                cr[p] = blend ? ncr : cr[p];
                cg[p] = blend ? ncg : cg[p];
                cbv[p] = blend ? ncb : cbv[p];
                cd[p] = blend ? ncd : cd[p];
                tr[p] = blend ? t_next : t;
                walked[p] = blend ? fi : walked[p];
                nbl[p] += blend ? 1 : 0;
                live[p] = (ok & (t_next < T_MIN)) ? 0 : live[p];
            }
        }
        for (int p = 0; p < LANES; ++p) {
            const int u = x0 + p % TILE, v = y0 + p / TILE;
            if (u < width && v < height) {
                const int64_t q = (int64_t)v * width + u;
                out_color[3 * q] = cr[p]; out_color[3 * q + 1] = cg[p]; out_color[3 * q + 2] = cbv[p];
                out_depth[q] = cd[p]; out_trans[q] = tr[p]; out_count[q] = (int32_t)walked[p];
                total += nbl[p];
            }
        }
    }
    return total;
}

extern "C" int64_t forward_pixel(const float* mx, const float* my, const float* ca, const float* cb,
                                 const float* cc, const float* op, const float* col, const float* z,
                                 const int64_t* offsets, const int32_t* ids, const int64_t* order,
                                 int64_t n_tiles, int width, int height, int n_threads, float* out_color,
                                 float* out_trans, float* out_depth, int32_t* out_count) {
    const int n_tx = (width + TILE - 1) / TILE;
    int64_t total = 0;
#pragma omp parallel for schedule(static) num_threads(n_threads) reduction(+ : total)
    for (int64_t k = 0; k < n_tiles; ++k) {
        const int64_t t = order[k];
        const int x0 = (int)(t % n_tx) * TILE, y0 = (int)(t / n_tx) * TILE;
        const int64_t start = offsets[t], n = offsets[t + 1] - start;
        for (int v = y0; v < y0 + TILE && v < height; ++v) {
            const float py = (float)v + HALF;
            for (int u = x0; u < x0 + TILE && u < width; ++u) {
                const float px = (float)u + HALF;
                float T = ONE, r = 0, gg = 0, bb = 0, d = 0;
                int32_t walked = 0;
                for (int64_t i = 0; i < n; ++i) {
                    const int g = ids[start + i];
                    const float dx = px - mx[g], dy = py - my[g];
                    const float power = HALF * (ca[g] * dx * dx + cc[g] * dy * dy) + cb[g] * dx * dy;
                    if (power > POWER_MAX) continue;
                    float alpha = op[g] * std::exp(-power);
                    if (alpha > ALPHA_MAX) alpha = ALPHA_MAX;
                    if (alpha < ALPHA_MIN) continue;
                    const float t_next = T * (ONE - alpha);
                    if (t_next < T_MIN) break;
                    const float w = alpha * T;
                    r += w * col[3 * g]; gg += w * col[3 * g + 1]; bb += w * col[3 * g + 2]; d += w * z[g];
                    T = t_next; walked = (int32_t)(i + 1); ++total;
                }
                const int64_t q = (int64_t)v * width + u;
                out_color[3 * q] = r; out_color[3 * q + 1] = gg; out_color[3 * q + 2] = bb;
                out_depth[q] = d; out_trans[q] = T; out_count[q] = walked;
            }
        }
    }
    return total;
}
