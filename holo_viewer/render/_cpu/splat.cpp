// Projection, binning and tile compositor of holo_viewer's fast splat renderer (see
// holo_viewer/render/fast.py).
//
// project_bin() projects the depth-ordered splats into every view, writing one packed 64-byte
// record per (view, splat) (layout of fast_kernels.py: rec with the box inside), and builds the
// per (view, tile) splat lists; composite() blends the records into the images, front to back
// per tile with early termination. Work items are (view, tile) pairs handed to std::threads
// from an atomic counter. The compositor's code paths, chosen at run time:
//   * AVX-512 (16x16 tiles): one 16-lane register per tile row, exact ellipse test on the
//     exponent, per-row live masks, records prefetched ahead;
//   * AVX2 + FMA (x86-64 with GCC/Clang): 16x16 tiles as the AVX-512 path in two 8-lane halves
//     per row; other tile sizes (multiples of 8): chords and 8-pixel chunks, branch-free
//     blending, finished rows skipped, polynomial exp;
//   * portable scalar: the same arithmetic one pixel at a time.
// warp_u8() is view_synthesis' float32 depth warp into the uint8 quilt (the live path), the numba
// kernel's bytes at ~0.6x its CPU (AVX-512 permutes from row windows; see the kernel's comment).
// Plain CPython API + buffer protocol: no build dependency beyond a C++17 compiler.
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <memory>
#include <mutex>
#include <thread>
#include <vector>

#include "hv_common.h"

namespace {

using hv::cpu_has_avx2;
using hv::cpu_has_avx512;
using hv::need;
using hv::parallel_for;

// One 64-byte record per (view, splat): floats u, v, conic A, B, C, opacity, r, g, b,
// q = 2 ln(opacity/threshold), then the int32 pixel box x0, x1, y0, y1 (fast_kernels.py REC_STRIDE, BOX_AT).
constexpr int REC = 16;            // floats per record
constexpr int BOX_AT = 10;         // word offset of the box in the record
constexpr int CAM = 29;            // doubles per view in project_bin's cams (fast_kernels.project_views)
constexpr float EXP_LO = -12.8f;   // exp(x < EXP_LO) treated as exp(EXP_LO); alpha_threshold >= 1e-5

struct Job {
    const float* rec;               // (nv, m, REC) records, box in words BOX_AT..BOX_AT+3
    const int64_t* off;
    const int64_t* base;
    const int32_t* ids;
    int nv, m, tile, tiles_x, tiles_y, width, height;
    float thr, cap, tmin;
    float bg[3];
    int clip;
    float* out;
    int64_t* blends;
    const int32_t* sel;             // the (view * tiles + tile) jobs to run, or nullptr: all of them
    int64_t n_sel;
};

inline float fast_exp(float x) {
    // Taylor degree 6 of x/32, squared 5 times: relative error < 2e-5 on [EXP_LO, 0].
    float y = std::max(x, EXP_LO) * (1.0f / 32.0f);
    float e = 1.0f + y * (1.0f + y * 0.5f * (1.0f + y * (1.0f / 3.0f) * (1.0f + y * 0.25f * (
                  1.0f + y * 0.2f * (1.0f + y * (1.0f / 6.0f))))));
    e = e * e; e = e * e; e = e * e; e = e * e;
    return e * e;
}

// Per-thread tile accumulators, 64-byte aligned: 32-byte loads of a store that split a cache
// line cannot be store-forwarded, which stalls every blend of the next splat on the same pixels.
template <typename X>
struct AlignedArray {
    std::vector<X> raw;
    X* ptr;
    explicit AlignedArray(int n) : raw(n + 64 / sizeof(X)) {
        auto a = reinterpret_cast<std::uintptr_t>(raw.data());
        ptr = reinterpret_cast<X*>((a + 63) & ~std::uintptr_t(63));
    }
    X& operator[](int i) { return ptr[i]; }
    const X& operator[](int i) const { return ptr[i]; }
    X* begin() { return ptr; }
    X* end() { return ptr + raw.size() - 64 / sizeof(X); }
};

struct TileBuf {
    AlignedArray<float> T, R, G, B;
    AlignedArray<int32_t> live;   // scalar path: 1 = still compositing; AVX2 path: all-ones mask
    std::vector<int> row_live;
    explicit TileBuf(int tile)
        : T(tile * tile), R(tile * tile), G(tile * tile), B(tile * tile), live(tile * tile), row_live(tile) {}
};

void write_tile(const Job& J, int v, int px0, int py0, int pw, int ph, const TileBuf& b) {
    for (int y = 0; y < ph; ++y) {
        float* o = J.out + ((int64_t(v) * J.height + (py0 + y)) * J.width + px0) * 3;
        for (int x = 0; x < pw; ++x) {
            int p = y * J.tile + x;
            float t = b.T[p];
            float c[3] = {b.R[p] + t * J.bg[0], b.G[p] + t * J.bg[1], b.B[p] + t * J.bg[2]};
            for (int ch = 0; ch < 3; ++ch) {
                float val = c[ch];
                if (J.clip) val = std::min(std::max(val, 0.0f), 1.0f);
                o[x * 3 + ch] = val;
            }
        }
    }
}

// Tile-local box of splat k (in view v) intersected with the tile; false when empty.
inline bool tile_box(const Job& J, int v, int k, int px0, int py0, int pw, int ph,
                     int& x0, int& x1, int& y0, int& y1) {
    int32_t bx[4];
    std::memcpy(bx, J.rec + (int64_t(v) * J.m + k) * REC + BOX_AT, sizeof(bx));
    x0 = std::max(bx[0], px0) - px0;
    x1 = std::min(bx[1], px0 + pw) - px0;
    y0 = std::max(bx[2], py0) - py0;
    y1 = std::min(bx[3], py0 + ph) - py0;
    return x0 < x1 && y0 < y1;
}

// Columns [xs0, xs1) of row dy (offset from the splat centre) inside the ellipse d^T conic d <= q
// where alpha >= threshold, widened by a small slack and clipped to [x0, x1); false when empty.
// Exact skipping: pixels outside the ellipse fail the alpha test anyway.
inline bool row_span(float A, float B, float C, float q, float u, float dy, int x0, int x1, int& xs0, int& xs1) {
    const float D = dy * dy * (B * B - A * C) + A * q;
    if (!(D >= 0.0f)) {
        // tiny negative values can come from rounding: keep the row when in doubt
        if (D < -1e-4f * A * q) return false;
    }
    const float half = std::sqrt(std::max(D, 0.0f)) / A * 1.0001f + 1e-2f;
    const float xc = u - B * dy / A;
    const float lo = std::ceil(xc - half), hi = std::floor(xc + half) + 1.0f;
    xs0 = lo > float(x0) ? int(lo) : x0;
    xs1 = hi < float(x1) ? int(hi) : x1;
    return xs0 < xs1;
}

int64_t tile_scalar(const Job& J, int v, int t, TileBuf& b) {
    const int tile = J.tile;
    const int ty = t / J.tiles_x, tx = t % J.tiles_x;
    const int px0 = tx * tile, py0 = ty * tile;
    const int pw = std::min(tile, J.width - px0), ph = std::min(tile, J.height - py0);
    std::fill(b.T.begin(), b.T.end(), 1.0f);
    std::fill(b.R.begin(), b.R.end(), 0.0f);
    std::fill(b.G.begin(), b.G.end(), 0.0f);
    std::fill(b.B.begin(), b.B.end(), 0.0f);
    std::fill(b.live.begin(), b.live.end(), 1);
    int n_live = pw * ph;
    int64_t nbl = 0;
    const int64_t nt = int64_t(J.tiles_x) * J.tiles_y;
    const int64_t* off = J.off + int64_t(v) * (nt + 1);
    const int32_t* ids = J.ids + J.base[v];
    for (int64_t e = off[t]; e < off[t + 1] && n_live > 0; ++e) {
        const int k = ids[e];
        int x0, x1, y0, y1;
        if (!tile_box(J, v, k, px0, py0, pw, ph, x0, x1, y0, y1)) continue;
        const float* r = J.rec + (int64_t(v) * J.m + k) * REC;
        const float u = r[0] - (float(px0) + 0.5f), vv = r[1] - (float(py0) + 0.5f);
        const float ca = -0.5f * r[2], cb = r[3], cc = -0.5f * r[4], op = r[5];
        for (int y = y0; y < y1; ++y) {
            const float dy = float(y) - vv;
            int xs0, xs1;
            if (!row_span(r[2], r[3], r[4], r[9], u, dy, x0, x1, xs0, xs1)) continue;
            const float lin = -cb * dy, cst = cc * dy * dy;
            for (int x = xs0; x < xs1; ++x) {
                const int p = y * tile + x;
                if (!b.live[p]) continue;
                const float dx = float(x) - u;
                const float power = (ca * dx + lin) * dx + cst;
                const float alpha = std::min(J.cap, op * fast_exp(power));
                if (!(power <= 0.0f) || alpha < J.thr) continue;
                const float tt = b.T[p];
                const float test = tt * (1.0f - alpha);
                const float w = alpha * tt;  // blended, then the pixel stops if T fell below t_min
                b.R[p] += w * r[6]; b.G[p] += w * r[7]; b.B[p] += w * r[8];
                b.T[p] = test;
                ++nbl;
                if (test < J.tmin) { b.live[p] = 0; --n_live; }
            }
        }
    }
    write_tile(J, v, px0, py0, pw, ph, b);
    return nbl;
}

#if HV_HAVE_AVX2_PATH
// Per-tile AVX2 compositor. Per splat: (1) the chord [lo, hi) of its alpha >= threshold ellipse
// on each of its rows in the tile, 8 rows per vector (a sqrt per row), clipped to its box;
// (2) the list of 8-pixel chunks that overlap a chord and still hold a live pixel (per-row
// bitmask of live chunks); (3) one flat loop over that list. A finished pixel keeps its
// transmittance with the sign flipped (T < 0 = done), so no separate live mask is loaded or
// stored; pixels outside the image start finished. The alpha test is done on the exponent:
// alpha >= thr  <=>  power >= log2(thr / opacity) (log2 e folded into the conic), so the
// exp2 needs no range clamp (lanes that fail the test are masked out).
constexpr float LOG2E = 1.4426950408889634f;

__attribute__((target("avx2,fma"))) inline __m256 fast_exp2_8(__m256 t) {
    // 2^t = 2^n 2^f, n = round(t), f in [-0.5, 0.5]; 2^f: degree-4 polynomial fitted for minimax
    // relative error on [-0.5, 0.5] (2.9e-6 in float32, as the degree-5 Taylor it replaced)
    const __m256 n = _mm256_round_ps(t, _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC);
    const __m256 f = _mm256_sub_ps(t, n);
    __m256 e = _mm256_fmadd_ps(f, _mm256_set1_ps(0.009585633873939514f), _mm256_set1_ps(0.05590590462088585f));
    e = _mm256_fmadd_ps(e, f, _mm256_set1_ps(0.2402404099702835f));
    e = _mm256_fmadd_ps(e, f, _mm256_set1_ps(0.6931242942810059f));
    e = _mm256_fmadd_ps(e, f, _mm256_set1_ps(1.0f));
    const __m256i bits = _mm256_slli_epi32(_mm256_cvtps_epi32(n), 23);
    return _mm256_castsi256_ps(_mm256_add_epi32(_mm256_castps_si256(e), bits));
}

struct AvxScratch {
    AlignedArray<float> lin, cst, lo, hi, dxc;  // per row: power terms, chord bounds in dx; per chunk column: dx
    AlignedArray<uint32_t> row_chunks;          // per row: bit c set while chunk c has a live pixel
    AlignedArray<uint32_t> row_bits;            // per row of the current splat: live chunks overlapping its chord
    std::vector<int32_t> item_p, item_y;        // chunk list of the current splat
    explicit AvxScratch(int tile)
        : lin(tile + 8), cst(tile + 8), lo(tile + 8), hi(tile + 8), dxc(tile),
          row_chunks(tile + 8), row_bits(tile + 8), item_p(tile * tile / 8 + 8), item_y(tile * tile / 8 + 8) {}
};

// Shared by the two 16x16 row compositors (AVX2 and AVX-512): the tile's geometry, per-row live
// masks and accumulators, and the next splat of its list with its box clipped to the tile.
constexpr int PREFETCH = 16;  // records are prefetched this many list entries ahead

struct Row16Tile {
    int px0, py0, pw, ph, n_live;
    const int32_t* ids;
    const float* recv;
    int64_t e_end;
    alignas(64) uint16_t rowlive[16];
};

inline int64_t row16_begin(const Job& J, int v, int t, TileBuf& b, Row16Tile& S) {
    constexpr int tile = 16;
    const int ty = t / J.tiles_x, tx = t % J.tiles_x;
    S.px0 = tx * tile;
    S.py0 = ty * tile;
    S.pw = std::min(tile, J.width - S.px0);
    S.ph = std::min(tile, J.height - S.py0);
    const uint16_t full = uint16_t((1u << S.pw) - 1u);
    for (int y = 0; y < tile; ++y) S.rowlive[y] = y < S.ph ? full : 0;
    S.n_live = S.pw * S.ph;
    std::fill(b.T.begin(), b.T.end(), 1.0f);
    std::fill(b.R.begin(), b.R.end(), 0.0f);
    std::fill(b.G.begin(), b.G.end(), 0.0f);
    std::fill(b.B.begin(), b.B.end(), 0.0f);
    const int64_t nt = int64_t(J.tiles_x) * J.tiles_y;
    const int64_t* off = J.off + int64_t(v) * (nt + 1);
    S.ids = J.ids + J.base[v];
    S.recv = J.rec + int64_t(v) * J.m * REC;
    S.e_end = off[t + 1];
    // the list's first records at once (row16_splat prefetches PREFETCH entries ahead from there on)
    for (int64_t e = off[t]; e < std::min(off[t] + PREFETCH, S.e_end); ++e)
        _mm_prefetch(reinterpret_cast<const char*>(S.recv + int64_t(S.ids[e]) * REC), _MM_HINT_T0);
    return off[t];
}

struct Row16Splat {
    const float* r;          // the record
    int y0, y1;              // tile rows [y0, y1)
    uint32_t xm;             // tile columns of its box, one bit each
    float u, vv, lop;        // centre relative to the tile's first pixel centre; log2 opacity
};

// Entry e of the tile's list; false when its box misses the tile.
HV_ALWAYS_INLINE inline bool row16_splat(const Row16Tile& S, int64_t e, float l2thr, Row16Splat& o) {
    _mm_prefetch(reinterpret_cast<const char*>(S.recv + int64_t(S.ids[std::min(e + PREFETCH, S.e_end - 1)]) * REC),
                 _MM_HINT_T0);
    _mm_prefetch(reinterpret_cast<const char*>(S.recv + int64_t(S.ids[std::min(e + 4 * PREFETCH, S.e_end - 1)]) * REC),
                 _MM_HINT_T1);
    const float* r = S.recv + int64_t(S.ids[e]) * REC;
    int32_t bx[4];
    std::memcpy(bx, r + BOX_AT, sizeof(bx));
    const int x0 = std::max(bx[0], S.px0) - S.px0, x1 = std::min(bx[1], S.px0 + S.pw) - S.px0;
    o.y0 = std::max(bx[2], S.py0) - S.py0;
    o.y1 = std::min(bx[3], S.py0 + S.ph) - S.py0;
    if (x0 >= x1 || o.y0 >= o.y1) return false;
    o.r = r;
    o.xm = ((1u << x1) - 1u) & ~((1u << x0) - 1u);
    o.u = r[0] - (float(S.px0) + 0.5f);
    o.vv = r[1] - (float(S.py0) + 0.5f);
    o.lop = r[9] * (0.5f * LOG2E) + l2thr;  // log2 opacity from q = 2 ln(opacity / threshold)
    return true;
}

// Per-tile AVX2 compositor for 16x16 tiles: the AVX-512 path's row design with each 16-pixel
// tile row in two 8-lane halves and vector masks in place of mask registers (CPUs without
// AVX-512). exp2 lanes that fail the alpha test may hold garbage (the exponent is not clamped);
// every use is masked bitwise, never multiplied in.
__attribute__((target("avx2,fma,popcnt"))) int64_t tile_avx2_rows(const Job& J, int v, int t, TileBuf& b) {
    constexpr int tile = 16;  // checked by the caller
    Row16Tile S;
    const int64_t e_begin = row16_begin(J, v, t, b, S);
    uint16_t* rowlive = S.rowlive;
    float* __restrict Tp = b.T.ptr;
    float* __restrict Rp = b.R.ptr;
    float* __restrict Gp = b.G.ptr;
    float* __restrict Bp = b.B.ptr;
    const __m256 lane = _mm256_setr_ps(0.f, 1.f, 2.f, 3.f, 4.f, 5.f, 6.f, 7.f);
    const __m256i bit0 = _mm256_setr_epi32(1, 2, 4, 8, 16, 32, 64, 128);
    const __m256i bit1 = _mm256_slli_epi32(bit0, 8);
    const __m256 vcap = _mm256_set1_ps(J.cap), vtmin = _mm256_set1_ps(J.tmin);
    const float l2thr = std::log2(J.thr);
    const __m256 vthr = _mm256_set1_ps(l2thr);
    __m256i count = _mm256_setzero_si256();
    Row16Splat sp;
    for (int64_t e = e_begin; e < S.e_end && S.n_live > 0; ++e) {
        if (!row16_splat(S, e, l2thr, sp)) continue;
        const float* r = sp.r;
        const int y0 = sp.y0, y1 = sp.y1;
        const uint32_t xm = sp.xm;
        const float u = sp.u, vv = sp.vv, lop = sp.lop;
        const __m256 ca = _mm256_set1_ps(-0.5f * r[2] * LOG2E), cb = _mm256_set1_ps(-r[3] * LOG2E);
        const __m256 dx0 = _mm256_sub_ps(lane, _mm256_set1_ps(u));
        const __m256 dx1 = _mm256_add_ps(dx0, _mm256_set1_ps(8.0f));
        const __m256 p00 = _mm256_fmadd_ps(_mm256_mul_ps(ca, dx0), dx0, _mm256_set1_ps(lop));
        const __m256 p01 = _mm256_fmadd_ps(_mm256_mul_ps(ca, dx1), dx1, _mm256_set1_ps(lop));
        const __m256 pb0 = _mm256_mul_ps(cb, dx0), pb1 = _mm256_mul_ps(cb, dx1);
        const float kc = -0.5f * r[4] * LOG2E;
        const __m256 cr = _mm256_set1_ps(r[6]), cg = _mm256_set1_ps(r[7]), cbl = _mm256_set1_ps(r[8]);
        // the exponent by second differences, as the AVX-512 path (same values)
        const float dy0 = float(y0) - vv;
        const __m256 vdy0 = _mm256_set1_ps(dy0), vc0 = _mm256_set1_ps(kc * dy0 * dy0);
        const __m256 vd0 = _mm256_set1_ps(kc * (2.0f * dy0 + 1.0f)), ddpow = _mm256_set1_ps(2.0f * kc);
        __m256 pw[2] = {_mm256_add_ps(_mm256_fmadd_ps(pb0, vdy0, p00), vc0),
                        _mm256_add_ps(_mm256_fmadd_ps(pb1, vdy0, p01), vc0)};
        __m256 dp[2] = {_mm256_add_ps(pb0, vd0), _mm256_add_ps(pb1, vd0)};
        for (int y = y0; y < y1; ++y) {
            const __m256 pw_y[2] = {pw[0], pw[1]};
            for (int h = 0; h < 2; ++h) {
                pw[h] = _mm256_add_ps(pw[h], dp[h]);
                dp[h] = _mm256_add_ps(dp[h], ddpow);
            }
            const uint32_t live = rowlive[y] & xm;
            if (!live) continue;
            const __m256i vlive = _mm256_set1_epi32(int(live));
            uint32_t fin16 = 0;
            // two 8-pixel halves of the row
            for (int h = 0; h < 2; ++h) {
                const __m256i bits = h ? bit1 : bit0;
                const __m256 lm = _mm256_castsi256_ps(
                    _mm256_cmpeq_epi32(_mm256_and_si256(vlive, bits), bits));
                const __m256 power = pw_y[h];
                const __m256 m = _mm256_and_ps(lm, _mm256_cmp_ps(power, vthr, _CMP_GE_OQ));
                const __m256 alpha = _mm256_min_ps(vcap, fast_exp2_8(power));
                float* Ty = Tp + y * tile + 8 * h;
                const __m256 T = _mm256_load_ps(Ty);
                const __m256 test = _mm256_fnmadd_ps(T, alpha, T);
                const __m256 fin = _mm256_and_ps(m, _mm256_cmp_ps(test, vtmin, _CMP_LT_OQ));
                const __m256 ok = m;  // blended even when it finishes the pixel
                const __m256 w = _mm256_and_ps(ok, _mm256_mul_ps(alpha, T));
                float* Ry = Rp + y * tile + 8 * h;
                float* Gy = Gp + y * tile + 8 * h;
                float* By = Bp + y * tile + 8 * h;
                _mm256_store_ps(Ry, _mm256_fmadd_ps(w, cr, _mm256_load_ps(Ry)));
                _mm256_store_ps(Gy, _mm256_fmadd_ps(w, cg, _mm256_load_ps(Gy)));
                _mm256_store_ps(By, _mm256_fmadd_ps(w, cbl, _mm256_load_ps(By)));
                _mm256_store_ps(Ty, _mm256_blendv_ps(T, test, ok));
                count = _mm256_sub_epi32(count, _mm256_castps_si256(ok));
                fin16 |= uint32_t(_mm256_movemask_ps(fin)) << (8 * h);
            }
            rowlive[y] &= uint16_t(~fin16);
            S.n_live -= __builtin_popcount(fin16);
        }
    }
    write_tile(J, v, S.px0, S.py0, S.pw, S.ph, b);
    alignas(32) int32_t cnt[8];
    _mm256_store_si256(reinterpret_cast<__m256i*>(cnt), count);
    int64_t nbl = 0;
    for (int j = 0; j < 8; ++j) nbl += cnt[j];
    return nbl;
}

__attribute__((target("avx2,fma"))) int64_t tile_avx2(const Job& J, int v, int t, TileBuf& b, AvxScratch& s) {
    const int tile = J.tile;  // multiple of 8, <= 256 (checked by the caller)
    const int ty = t / J.tiles_x, tx = t % J.tiles_x;
    const int px0 = tx * tile, py0 = ty * tile;
    const int pw = std::min(tile, J.width - px0), ph = std::min(tile, J.height - py0);
    int n_live = pw * ph;
    for (int y = 0; y < tile; ++y) {
        uint32_t bits = 0;
        for (int x = 0; x < tile; ++x) {
            const bool in = y < ph && x < pw;
            b.T[y * tile + x] = in ? 1.0f : -1.0f;
            if (in) bits |= 1u << (x >> 3);
        }
        s.row_chunks[y] = bits;
    }
    std::fill(b.R.begin(), b.R.end(), 0.0f);
    std::fill(b.G.begin(), b.G.end(), 0.0f);
    std::fill(b.B.begin(), b.B.end(), 0.0f);
    const int64_t nt = int64_t(J.tiles_x) * J.tiles_y;
    const int64_t* off = J.off + int64_t(v) * (nt + 1);
    const int32_t* ids = J.ids + J.base[v];
    const __m256 lane = _mm256_setr_ps(0.f, 1.f, 2.f, 3.f, 4.f, 5.f, 6.f, 7.f);
    const __m256 zero = _mm256_setzero_ps(), sign = _mm256_set1_ps(-0.0f);
    const __m256 vcap = _mm256_set1_ps(J.cap), vtmin = _mm256_set1_ps(J.tmin);
    __m256i count = _mm256_setzero_si256();
    constexpr int GATHER = 32;
    alignas(64) float gr[GATHER][REC];
    int n_g = 0, i_g = 0;
    const int chunks = tile / 8;
    for (int64_t e = off[t]; e < off[t + 1] && n_live > 0; ++e) {
        if (i_g == n_g) {
            n_g = int(std::min<int64_t>(GATHER, off[t + 1] - e));
            for (int j = 0; j < n_g; ++j) {
                const int64_t kj = int64_t(v) * J.m + ids[e + j];
                std::memcpy(gr[j], J.rec + kj * REC, sizeof(float) * REC);
            }
            i_g = 0;
        }
        const float* r = gr[i_g];
        int32_t bx[4];
        std::memcpy(bx, r + BOX_AT, sizeof(bx));
        ++i_g;
        const int x0 = std::max(bx[0], px0) - px0, x1 = std::min(bx[1], px0 + pw) - px0;
        const int y0 = std::max(bx[2], py0) - py0, y1 = std::min(bx[3], py0 + ph) - py0;
        if (x0 >= x1 || y0 >= y1) continue;
        const float u = r[0] - (float(px0) + 0.5f), vv = r[1] - (float(py0) + 0.5f);
        const float A = r[2], Bc = r[3], C = r[4], q = r[9];
        // (1) chords, 8 rows at a time
        {
            const __m256 vA = _mm256_set1_ps(A), vq = _mm256_set1_ps(q);
            const __m256 iA = _mm256_set1_ps(1.0f / A);
            const __m256 kdd = _mm256_set1_ps(Bc * Bc - A * C), Aq = _mm256_mul_ps(vA, vq);
            const __m256 negtol = _mm256_mul_ps(Aq, _mm256_set1_ps(-1e-4f));
            const __m256 vu = _mm256_set1_ps(u), vvv = _mm256_set1_ps(vv), vB = _mm256_set1_ps(Bc);
            const __m256 vx0 = _mm256_set1_ps(float(x0)), vx1 = _mm256_set1_ps(float(x1));
            const __m256 klin = _mm256_set1_ps(-Bc * LOG2E), kcst = _mm256_set1_ps(-0.5f * C * LOG2E);
            const __m256 half_pix = _mm256_set1_ps(0.5f);
            for (int y = y0; y < y1; y += 8) {
                const __m256 dy = _mm256_sub_ps(_mm256_add_ps(_mm256_set1_ps(float(y)), lane), vvv);
                const __m256 D = _mm256_fmadd_ps(_mm256_mul_ps(dy, dy), kdd, Aq);
                const __m256 keep = _mm256_cmp_ps(D, negtol, _CMP_GE_OQ);
                const __m256 half = _mm256_add_ps(
                    _mm256_mul_ps(_mm256_mul_ps(_mm256_sqrt_ps(_mm256_max_ps(D, zero)), iA), _mm256_set1_ps(1.0001f)),
                    _mm256_set1_ps(1e-2f));
                const __m256 xc = _mm256_fnmadd_ps(_mm256_mul_ps(vB, dy), iA, vu);
                __m256 lo = _mm256_ceil_ps(_mm256_sub_ps(xc, half));
                __m256 hi = _mm256_add_ps(_mm256_floor_ps(_mm256_add_ps(xc, half)), _mm256_set1_ps(1.0f));
                lo = _mm256_max_ps(lo, vx0);
                hi = _mm256_min_ps(hi, vx1);
                hi = _mm256_blendv_ps(vx0, hi, keep);  // dropped rows: empty chord
                // chunks c0..c1 of the chord as a bitmask (mod 2^32 the c1 = 31 case comes out right),
                // restricted to the row's live chunks; empty chords give 0
                const __m256i ilo = _mm256_cvttps_epi32(lo), ihi = _mm256_cvttps_epi32(hi);
                const __m256i c0 = _mm256_srai_epi32(ilo, 3);
                const __m256i c1 = _mm256_srai_epi32(_mm256_sub_epi32(ihi, _mm256_set1_epi32(1)), 3);
                __m256i bits = _mm256_sub_epi32(_mm256_sllv_epi32(_mm256_set1_epi32(2), c1),
                                                _mm256_sllv_epi32(_mm256_set1_epi32(1), c0));
                bits = _mm256_and_si256(bits, _mm256_cmpgt_epi32(ihi, ilo));
                bits = _mm256_and_si256(bits, _mm256_loadu_si256((const __m256i*)&s.row_chunks[y]));
                _mm256_store_si256((__m256i*)&s.row_bits[y - y0], bits);
                _mm256_storeu_ps(&s.lo[y], _mm256_sub_ps(_mm256_sub_ps(lo, half_pix), vu));
                _mm256_storeu_ps(&s.hi[y], _mm256_sub_ps(_mm256_sub_ps(hi, half_pix), vu));
                _mm256_storeu_ps(&s.lin[y], _mm256_mul_ps(klin, dy));
                _mm256_storeu_ps(&s.cst[y], _mm256_mul_ps(kcst, _mm256_mul_ps(dy, dy)));
            }
        }
        // (2) live chunks overlapping the chords
        int n_it = 0;
        // branch-free compaction: every chunk is written, the count advances by its bit
        {
            int32_t* __restrict ip = s.item_p.data();
            int32_t* __restrict iy = s.item_y.data();
            const uint32_t* __restrict rb = s.row_bits.ptr;
            for (int y = y0; y < y1; ++y) {
                const uint32_t bits = rb[y - y0];
                for (int c = 0; c < chunks; ++c) {
                    ip[n_it] = y * tile + c * 8;
                    iy[n_it] = y;
                    n_it += (bits >> c) & 1u;
                }
            }
        }
        if (n_it == 0) continue;
        for (int c = 0; c < chunks; ++c)
            _mm256_store_ps(&s.dxc[c * 8], _mm256_sub_ps(_mm256_add_ps(_mm256_set1_ps(float(c * 8)), lane),
                                                          _mm256_set1_ps(u)));
        // (3) blend
        const __m256 ca = _mm256_set1_ps(-0.5f * A * LOG2E);
        const __m256 pthr = _mm256_set1_ps(-0.5f * q * LOG2E);  // log2(thr / opacity)
        const __m256 op = _mm256_set1_ps(r[5]);
        const __m256 cr = _mm256_set1_ps(r[6]), cg = _mm256_set1_ps(r[7]), cbl = _mm256_set1_ps(r[8]);
        // raw restrict pointers: stores to the accumulators would otherwise force reloads of
        // every array pointer in the loop
        float* __restrict Tp = b.T.ptr;
        float* __restrict Rp = b.R.ptr;
        float* __restrict Gp = b.G.ptr;
        float* __restrict Bp = b.B.ptr;
        const float* __restrict lin = s.lin.ptr;
        const float* __restrict cst = s.cst.ptr;
        const float* __restrict lo = s.lo.ptr;
        const float* __restrict hi = s.hi.ptr;
        const float* __restrict dxc = s.dxc.ptr;
        const int32_t* __restrict ip = s.item_p.data();
        const int32_t* __restrict iy = s.item_y.data();
        uint32_t* __restrict rowc = s.row_chunks.ptr;
        for (int i = 0; i < n_it; ++i) {
            const int p = ip[i], y = iy[i];
            const __m256 tt = _mm256_load_ps(&Tp[p]);
            const __m256 dx = _mm256_load_ps(&dxc[p - y * tile]);
            const __m256 power = _mm256_fmadd_ps(_mm256_fmadd_ps(ca, dx, _mm256_broadcast_ss(&lin[y])), dx,
                                                 _mm256_broadcast_ss(&cst[y]));
            __m256 m = _mm256_and_ps(_mm256_cmp_ps(power, pthr, _CMP_GE_OQ), _mm256_cmp_ps(tt, zero, _CMP_GT_OQ));
            m = _mm256_and_ps(m, _mm256_and_ps(_mm256_cmp_ps(dx, _mm256_broadcast_ss(&lo[y]), _CMP_GT_OQ),
                                               _mm256_cmp_ps(dx, _mm256_broadcast_ss(&hi[y]), _CMP_LT_OQ)));
            const __m256 alpha = _mm256_min_ps(vcap, _mm256_mul_ps(op, fast_exp2_8(power)));
            const __m256 test = _mm256_fnmadd_ps(tt, alpha, tt);
            const __m256 fin = _mm256_and_ps(m, _mm256_cmp_ps(test, vtmin, _CMP_LT_OQ));
            const __m256 ok = m;  // blended even when it finishes the pixel
            const __m256 w = _mm256_and_ps(ok, _mm256_mul_ps(alpha, tt));
            _mm256_store_ps(&Rp[p], _mm256_fmadd_ps(w, cr, _mm256_load_ps(&Rp[p])));
            _mm256_store_ps(&Gp[p], _mm256_fmadd_ps(w, cg, _mm256_load_ps(&Gp[p])));
            _mm256_store_ps(&Bp[p], _mm256_fmadd_ps(w, cbl, _mm256_load_ps(&Bp[p])));
            const __m256 tn = _mm256_xor_ps(_mm256_blendv_ps(tt, test, ok), _mm256_and_ps(fin, sign));
            _mm256_store_ps(&Tp[p], tn);
            count = _mm256_sub_epi32(count, _mm256_castps_si256(ok));
            const int fm = _mm256_movemask_ps(fin);
            if (fm) {
                n_live -= __builtin_popcount(fm);
                if (_mm256_movemask_ps(_mm256_cmp_ps(tn, zero, _CMP_GT_OQ)) == 0)
                    rowc[y] &= ~(1u << ((p - y * tile) >> 3));
            }
        }
    }
    for (int p = 0; p < tile * tile; ++p) b.T[p] = std::fabs(b.T[p]);
    write_tile(J, v, px0, py0, pw, ph, b);
    alignas(32) int32_t cnt[8];
    _mm256_store_si256((__m256i*)cnt, count);
    int64_t nbl = 0;
    for (int j = 0; j < 8; ++j) nbl += cnt[j];
    return nbl;
}

// Per-tile AVX-512 compositor (16x16 tiles only): one 16-lane register per tile row, so the
// alpha >= threshold test on the exponent is the exact ellipse test and no chord or chunk list
// is needed. log2(opacity) is folded into the exponent (alpha = min(cap, 2^P), alpha >= thr
// <=> P >= log2 thr, with log2 opacity = q / (2 ln 2) + log2 thr from the record), finished
// pixels are cleared from a per-row 16-bit live mask, rows of the splat with no live pixel in
// its box columns are skipped. Records are gathered through the depth-ordered id list with a
// software prefetch PREFETCH entries ahead into L1 and 4 PREFETCH into L2, a tile's first
// PREFETCH at once (the record of a view is 6 MB for 100k splats: without it the record loads'
// cache misses took half the time). Same arithmetic as the AVX2
// path up to float rounding; 256-bit halves of the 512-bit ops on CPUs that split them.

HV_TARGET_AVX512 inline __m512 fast_exp2_16(__m512 t) {
    // same polynomial as fast_exp2_8; scalef applies 2^n
    const __m512 n = _mm512_roundscale_ps(t, _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC);
    const __m512 f = _mm512_sub_ps(t, n);
    __m512 e = _mm512_fmadd_ps(f, _mm512_set1_ps(0.009585633873939514f), _mm512_set1_ps(0.05590590462088585f));
    e = _mm512_fmadd_ps(e, f, _mm512_set1_ps(0.2402404099702835f));
    e = _mm512_fmadd_ps(e, f, _mm512_set1_ps(0.6931242942810059f));
    e = _mm512_fmadd_ps(e, f, _mm512_set1_ps(1.0f));
    return _mm512_scalef_ps(e, n);
}

// write_tile for a full-width 16-pixel tile row set: colour = R + T * bg (clipped), the three
// channels interleaved with two permutes per 16 output floats (same arithmetic as write_tile).
HV_TARGET_AVX512 void write_tile16(const Job& J, int v, int px0, int py0, int ph, const TileBuf& b) {
    alignas(64) int32_t i1[3][16], i2[3][16];
    for (int k = 0; k < 3; ++k)
        for (int j = 0; j < 16; ++j) {
            const int q = j + 16 * k, px = q / 3, ch = q % 3;
            i1[k][j] = ch == 0 ? px : ch == 1 ? 16 + px : 0;
            i2[k][j] = ch == 2 ? 16 + px : j;
        }
    const __m512 zero = _mm512_setzero_ps(), one = _mm512_set1_ps(1.0f);
    const __m512 bg0 = _mm512_set1_ps(J.bg[0]), bg1 = _mm512_set1_ps(J.bg[1]), bg2 = _mm512_set1_ps(J.bg[2]);
    for (int y = 0; y < ph; ++y) {
        const int p = y * 16;
        const __m512 T = _mm512_load_ps(b.T.ptr + p);
        __m512 R = _mm512_add_ps(_mm512_load_ps(b.R.ptr + p), _mm512_mul_ps(T, bg0));
        __m512 G = _mm512_add_ps(_mm512_load_ps(b.G.ptr + p), _mm512_mul_ps(T, bg1));
        __m512 B = _mm512_add_ps(_mm512_load_ps(b.B.ptr + p), _mm512_mul_ps(T, bg2));
        if (J.clip) {  // min(max(x, 0), 1) with std::min/max's operand order (exact for -0)
            R = _mm512_min_ps(one, _mm512_max_ps(zero, R));
            G = _mm512_min_ps(one, _mm512_max_ps(zero, G));
            B = _mm512_min_ps(one, _mm512_max_ps(zero, B));
        }
        float* o = J.out + ((int64_t(v) * J.height + (py0 + y)) * J.width + px0) * 3;
        for (int k = 0; k < 3; ++k) {
            const __m512 rg = _mm512_permutex2var_ps(R, _mm512_load_si512(i1[k]), G);
            _mm512_storeu_ps(o + 16 * k, _mm512_permutex2var_ps(rg, _mm512_load_si512(i2[k]), B));
        }
    }
}

HV_TARGET_AVX512 int64_t tile_avx512(const Job& J, int v, int t, TileBuf& b) {
    constexpr int tile = 16;  // checked by the caller
    Row16Tile S;
    const int64_t e_begin = row16_begin(J, v, t, b, S);
    uint16_t* rowlive = S.rowlive;
    float* __restrict Tp = b.T.ptr;
    float* __restrict Rp = b.R.ptr;
    float* __restrict Gp = b.G.ptr;
    float* __restrict Bp = b.B.ptr;
    const __m512 lane = _mm512_setr_ps(0.f, 1.f, 2.f, 3.f, 4.f, 5.f, 6.f, 7.f, 8.f, 9.f, 10.f, 11.f, 12.f, 13.f,
                                       14.f, 15.f);
    const __m512 vcap = _mm512_set1_ps(J.cap), vtmin = _mm512_set1_ps(J.tmin);
    const float l2thr = std::log2(J.thr);
    const __m512 vthr = _mm512_set1_ps(l2thr);
    int64_t nbl = 0;
    Row16Splat sp;
    for (int64_t e = e_begin; e < S.e_end && S.n_live > 0; ++e) {
        if (!row16_splat(S, e, l2thr, sp)) continue;
        const float* r = sp.r;
        const int y0 = sp.y0, y1 = sp.y1;
        const uint16_t xm = uint16_t(sp.xm);
        const float u = sp.u, vv = sp.vv, lop = sp.lop;
        const __m512 dx = _mm512_sub_ps(lane, _mm512_set1_ps(u));
        const __m512 p0 = _mm512_fmadd_ps(_mm512_mul_ps(_mm512_set1_ps(-0.5f * r[2] * LOG2E), dx), dx,
                                          _mm512_set1_ps(lop));
        const __m512 pb = _mm512_mul_ps(_mm512_set1_ps(-r[3] * LOG2E), dx);
        const float kc = -0.5f * r[4] * LOG2E;
        const __m512 cr = _mm512_set1_ps(r[6]), cg = _mm512_set1_ps(r[7]), cbl = _mm512_set1_ps(r[8]);
        // the exponent row by row by second differences, P(y+1) = P(y) + D(y), D(y+1) = D(y) + 2 kc
        // (two adds, no broadcasts: the compositor is bound by vector throughput; 8 % faster)
        const float dy0 = float(y0) - vv;
        __m512 power = _mm512_add_ps(_mm512_fmadd_ps(pb, _mm512_set1_ps(dy0), p0), _mm512_set1_ps(kc * dy0 * dy0));
        __m512 dpow = _mm512_add_ps(pb, _mm512_set1_ps(kc * (2.0f * dy0 + 1.0f)));
        const __m512 ddpow = _mm512_set1_ps(2.0f * kc);
        for (int y = y0; y < y1; ++y, power = _mm512_add_ps(power, dpow), dpow = _mm512_add_ps(dpow, ddpow)) {
            const __mmask16 live = rowlive[y] & xm;
            if (!live) continue;  // skipping dead rows beats evaluating them (measured)
            const __mmask16 m = _mm512_mask_cmp_ps_mask(live, power, vthr, _CMP_GE_OQ);
            const __m512 alpha = _mm512_min_ps(vcap, fast_exp2_16(power));
            float* Ty = Tp + y * tile;
            const __m512 T = _mm512_load_ps(Ty);
            const __m512 test = _mm512_fnmadd_ps(T, alpha, T);
            const __mmask16 fin = _mm512_mask_cmp_ps_mask(m, test, vtmin, _CMP_LT_OQ);
            const __mmask16 ok = m;  // blended even when it finishes the pixel
            // every lane computed and stored unmasked (w = 0 where not blending): GCC turned a
            // masked blend + store into a masked store, which the next splat's load of the same
            // row cannot take by store forwarding (12% slower, measured)
            const __m512 w = _mm512_maskz_mul_ps(ok, alpha, T);
            _mm512_store_ps(Rp + y * tile, _mm512_fmadd_ps(w, cr, _mm512_load_ps(Rp + y * tile)));
            _mm512_store_ps(Gp + y * tile, _mm512_fmadd_ps(w, cg, _mm512_load_ps(Gp + y * tile)));
            _mm512_store_ps(Bp + y * tile, _mm512_fmadd_ps(w, cbl, _mm512_load_ps(Bp + y * tile)));
            _mm512_store_ps(Ty, _mm512_mask_mov_ps(T, ok, test));
            nbl += __builtin_popcount(ok);
            // branch-free: a branch on fin mispredicted often enough to cost 15% (measured)
            rowlive[y] &= uint16_t(~fin);
            S.n_live -= __builtin_popcount(fin);
        }
    }
    if (S.pw == tile) write_tile16(J, v, S.px0, S.py0, S.ph, b);
    else write_tile(J, v, S.px0, S.py0, S.pw, S.ph, b);
    return nbl;
}

#endif

enum class Path { scalar, avx2, avx512 };

void run_jobs(const Job& J, int n_threads, Path path) {
    const int64_t nt = int64_t(J.tiles_x) * J.tiles_y;
    const int64_t n_jobs = J.sel ? J.n_sel : nt * J.nv;
    std::atomic<int64_t> next{0};
    auto worker = [&]() {
        TileBuf b(J.tile);
#if HV_HAVE_AVX2_PATH
        AvxScratch s(path == Path::avx2 ? J.tile : 8);
#endif
        for (;;) {
            const int64_t i = next.fetch_add(1);
            if (i >= n_jobs) break;
            const int64_t job = J.sel ? int64_t(J.sel[i]) : i;
            const int v = int(job / nt), t = int(job % nt);
            int64_t nbl;
#if HV_HAVE_AVX2_PATH
            nbl = path == Path::avx512 ? tile_avx512(J, v, t, b)
                  : path == Path::avx2 ? (J.tile == 16 ? tile_avx2_rows(J, v, t, b) : tile_avx2(J, v, t, b, s))
                                       : tile_scalar(J, v, t, b);
#else
            (void)path;
            nbl = tile_scalar(J, v, t, b);
#endif
            J.blends[job] = nbl;
        }
    };
    n_threads = int(std::max<int64_t>(1, std::min<int64_t>(n_threads, n_jobs)));
    std::vector<std::thread> pool;
    for (int i = 1; i < n_threads; ++i) pool.emplace_back(worker);
    worker();
    for (auto& th : pool) th.join();
}


PyObject* composite(PyObject*, PyObject* args) {
    Py_buffer rec{}, off{}, base{}, ids{}, bg{}, out{}, blends{}, sel{};
    int nv, m, tile, tiles_x, tiles_y, width, height, clip, n_threads, mode;
    double thr, cap, tmin;
    if (!PyArg_ParseTuple(args, "y*y*y*y*iiiiiiidddy*pw*w*iiy*", &rec, &off, &base, &ids, &nv, &m, &tile,
                          &tiles_x, &tiles_y, &width, &height, &thr, &cap, &tmin, &bg, &clip, &out, &blends,
                          &n_threads, &mode, &sel))
        return nullptr;
    PyObject* result = nullptr;
    const int64_t nt = int64_t(tiles_x) * tiles_y;
    bool ok = nv > 0 && m >= 0 && tile > 0 && tiles_x > 0 && tiles_y > 0 && width > 0 && height > 0 &&
              int64_t(tiles_x) * tile >= width && int64_t(tiles_y) * tile >= height;
    if (!ok) PyErr_SetString(PyExc_ValueError, "_splat_cpp.composite: inconsistent sizes");
    ok = ok && need(rec, Py_ssize_t(nv) * m * REC * 4, "rec") &&
         need(off, Py_ssize_t(nv) * (nt + 1) * 8, "off") && need(base, Py_ssize_t(nv) * 8, "base") &&
         need(bg, 12, "bg") && need(out, Py_ssize_t(nv) * height * width * 12, "out") &&
         need(blends, Py_ssize_t(nv) * nt * 8, "blends");
    if (ok) {
        Job J{};
        J.rec = (const float*)rec.buf; J.off = (const int64_t*)off.buf;
        J.base = (const int64_t*)base.buf; J.ids = (const int32_t*)ids.buf;
        J.nv = nv; J.m = m; J.tile = tile; J.tiles_x = tiles_x; J.tiles_y = tiles_y;
        J.width = width; J.height = height;
        J.thr = float(thr); J.cap = float(cap); J.tmin = float(tmin);
        std::memcpy(J.bg, bg.buf, 12);
        J.clip = clip; J.out = (float*)out.buf; J.blends = (int64_t*)blends.buf;
        // jobs: int32 (view * tiles + tile) indices of the tiles to composite (others are not
        // written); an empty buffer composites every tile
        J.n_sel = sel.len / 4;
        J.sel = J.n_sel > 0 ? (const int32_t*)sel.buf : nullptr;
        for (int64_t i = 0; i < J.n_sel && ok; ++i)
            if (J.sel[i] < 0 || J.sel[i] >= int64_t(nv) * nt) ok = false;
        if (!ok) PyErr_SetString(PyExc_ValueError, "_splat_cpp.composite: a job index is outside 0 .. nv * tiles");
        // every tile list must stay inside ids
        const int64_t n_ids = ids.len / 4;
        bool lists_ok = true;
        for (int v = 0; v < nv && ok; ++v) {
            const int64_t last = J.base[v] + J.off[int64_t(v) * (nt + 1) + nt];
            if (J.base[v] < 0 || last > n_ids) lists_ok = false;
        }
        if (ok && !lists_ok) PyErr_SetString(PyExc_ValueError, "_splat_cpp.composite: tile lists exceed ids");
        ok = ok && lists_ok;
        // mode: 0 = auto (AVX-512 for 16x16 tiles, else AVX2, when the CPU has it), 1 = scalar,
        // 2 = require AVX2, 3 = require AVX-512
        const bool can2 = (tile % 8 == 0) && tile <= 256 && cpu_has_avx2();
        const bool can512 = tile == 16 && cpu_has_avx512();
        Path path = Path::scalar;
        if (mode == 0) path = can512 ? Path::avx512 : can2 ? Path::avx2 : Path::scalar;
        else if (mode == 2) path = Path::avx2;
        else if (mode == 3) path = Path::avx512;
        if (ok && ((mode == 2 && !can2) || (mode == 3 && !can512))) {
            PyErr_Format(PyExc_RuntimeError, "_splat_cpp.composite: %s path unavailable (CPU or tile size %d)",
                         mode == 2 ? "AVX2" : "AVX-512", tile);
            ok = false;
        }
        if (ok && (mode < 0 || mode > 3)) {
            PyErr_Format(PyExc_ValueError, "_splat_cpp.composite: mode: expected 0..3, found %d", mode);
            ok = false;
        }
        if (ok) {
            Py_BEGIN_ALLOW_THREADS
            run_jobs(J, n_threads, path);
            Py_END_ALLOW_THREADS
            result = PyUnicode_FromString(path == Path::avx512 ? "avx512" : path == Path::avx2 ? "avx2" : "scalar");
        }
    }
    PyBuffer_Release(&rec); PyBuffer_Release(&off); PyBuffer_Release(&base);
    PyBuffer_Release(&ids); PyBuffer_Release(&bg); PyBuffer_Release(&out); PyBuffer_Release(&blends);
    PyBuffer_Release(&sel);
    return result;
}

// x / tile for x >= 0: a shift for power-of-two tiles (an integer division cost 5% of binning)
struct TileDiv {
    int tile, shift;
    explicit TileDiv(int t) : tile(t), shift(-1) {
        for (int s = 0; s < 31; ++s)
            if ((1 << s) == t) shift = s;
    }
    int operator()(int x) const { return shift >= 0 ? x >> shift : x / tile; }
};

// ---- binning: per (view, tile) lists of splat indices in depth order -------------------------
// Same rule as fast_kernels.count_tiles / fill_tiles (float64, identical lists): a splat is listed
// in the tiles its alpha >= threshold ellipse reaches, per tile row the ellipse's x-extent over
// the band of rows (_band_tiles), widened by 0.05 px + 1e-3 relative. One evaluation per
// (splat, tile row), in the count pass, which records each (splat, tile) entry for the fill.
struct BinJob {
    const float* rec;
    int m, tile, tiles_x, tiles_y;
    std::atomic<bool>* bad;         // set when a box lies outside the tile grid
    TileDiv div{16};
};

struct Conic { double u, vv, A, iA, B, e, Aq, kk; };

inline Conic splat_conic(const float* r) {
    const double u = r[0], vv = r[1], A = r[2], B = r[3], C = r[4], q = r[9];
    const double det = A * C - B * B;
    if (!(det > 0.0 && A > 0.0 && C > 0.0 && q > 0.0)) return {u, vv, 0.0, 0.0, B, 0.0, 0.0, 0.0};
    const double hx = std::sqrt(q * C / det);
    return {u, vv, A, 1.0 / A, B, B * B - A * C, A * q, B * hx / C};
}


// tile columns [t0, t1] of the band of pixel rows ya..yb (inclusive), clipped to box columns [x0, x1)
inline void band_tiles(const Conic& c, const TileDiv& div, int x0, int x1, int ya, int yb, int& t0, int& t1) {
    int j0 = x0, j1 = x1 - 1;
    if (c.A > 0.0) {
        const double d0 = ya + 0.5 - c.vv, d1 = yb + 0.5 - c.vv;
        const double dr = std::min(std::max(-c.kk, d0), d1);
        const double dl = std::min(std::max(c.kk, d0), d1);
        const double sr = std::sqrt(std::max(dr * dr * c.e + c.Aq, 0.0));
        const double sl = std::sqrt(std::max(dl * dl * c.e + c.Aq, 0.0));
        const double xr = c.u + (-c.B * dr + sr * 1.001) * c.iA + 0.05;
        const double xl = c.u + (-c.B * dl - sl * 1.001) * c.iA - 0.05;
        const double cl = std::ceil(xl - 0.5), fr = std::floor(xr - 0.5);
        if (cl > double(j0)) j0 = cl > double(j1) ? j1 + 1 : int(cl);
        if (fr < double(j1)) j1 = fr < double(j0) ? j0 - 1 : int(fr);
    }
    if (j0 > j1) { t0 = 1; t1 = 0; return; }
    t0 = div(j0); t1 = div(j1);
}

// Calls f(k, t) for every tile t that splat k of view v reaches.
// pre: nullptr, or the pixel-column ranges (j0, j1) of the first two tile rows of the splat
// already computed by band_block (identical values).
template <typename F>
inline void entries_of(const BinJob& B, int v, int k, const int32_t* pre, F&& f) {
    const int tile = B.tile;
    const float* r = B.rec + (int64_t(v) * B.m + k) * REC;
    int32_t bx[4];
    std::memcpy(bx, r + BOX_AT, sizeof(bx));
    const int x0 = bx[0], x1 = bx[1], y0 = bx[2], y1 = bx[3];
    if (x0 >= x1 || y0 >= y1) return;
    if (x0 < 0 || y0 < 0 || int64_t(x1) > int64_t(B.tiles_x) * tile || int64_t(y1) > int64_t(B.tiles_y) * tile) {
        B.bad->store(true);
        return;
    }
    const TileDiv& div = B.div;
    const int tx0 = div(x0), tx1 = div(x1 - 1);
    const int ty0 = div(y0), ty1 = div(y1 - 1);
    if (tx0 == tx1) {  // one tile column: nothing to trim
        for (int ty = ty0; ty <= ty1; ++ty) f(k, ty * B.tiles_x + tx0);
        return;
    }
    Conic c{};
    if (!pre || ty1 - ty0 >= 2) c = splat_conic(r);
    for (int ty = ty0; ty <= ty1; ++ty) {
        int t0, t1;
        if (pre && ty - ty0 < 2) {
            const int j0 = pre[2 * (ty - ty0)], j1 = pre[2 * (ty - ty0) + 1];
            t0 = j0 > j1 ? 1 : div(j0);
            t1 = j0 > j1 ? 0 : div(j1);
        } else {
            band_tiles(c, div, x0, x1, std::max(y0, ty * tile), std::min(y1, ty * tile + tile) - 1, t0, t1);
        }
        for (int tx = t0; tx <= t1; ++tx) f(k, ty * B.tiles_x + tx);
    }
}


// ---- fused projection + binning (fast.py uses it with the C++ kernels) ------------------------
// Same forward pass as fast_kernels.project_views (float64, same formulas and order of
// operations) followed by the same tile lists as fast_kernels.count_tiles + fill_tiles, each
// record binned right after it is written, while it is in cache, instead of in a second sweep
// over every view's 6 MB of records. Inputs are in depth order. Work units are segments of the
// splat range, each projecting blocks of its splats into every view in turn (one read of the
// inputs per call); every (view, segment) keeps its own counts and entries, and the tile lists
// stay in depth order because segment s's entries of a tile go before segment s+1's.
constexpr double SH_C0 = 0.28209479177387814, SH_C1 = 0.4886025119029199;
constexpr double SH_C2[5] = {1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792,
                             0.5462742152960396};
constexpr double SH_C3[7] = {-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154,
                             -0.4570457994644658, 1.445305721320277, -0.5900435899266435};

inline void sh_basis(int degree, double x, double y, double z, double* b) {
    b[0] = SH_C0;
    if (degree >= 1) { b[1] = -SH_C1 * y; b[2] = SH_C1 * z; b[3] = -SH_C1 * x; }
    if (degree >= 2) {
        const double xx = x * x, yy = y * y, zz = z * z, xy = x * y, yz = y * z, xz = x * z;
        b[4] = SH_C2[0] * xy; b[5] = SH_C2[1] * yz; b[6] = SH_C2[2] * (2.0 * zz - xx - yy);
        b[7] = SH_C2[3] * xz; b[8] = SH_C2[4] * (xx - yy);
        if (degree >= 3) {
            b[9] = SH_C3[0] * y * (3.0 * xx - yy); b[10] = SH_C3[1] * xy * z;
            b[11] = SH_C3[2] * y * (4.0 * zz - xx - yy); b[12] = SH_C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy);
            b[13] = SH_C3[4] * x * (4.0 * zz - xx - yy); b[14] = SH_C3[5] * z * (xx - yy);
            b[15] = SH_C3[6] * x * (xx - 3.0 * yy);
        }
    }
}

struct ProjJob {
    // inputs in depth order, structure of arrays with row stride mp (a multiple of 8 >= m; the
    // padding has opacity 0): pc (3, mp), cov (6, mp), means (3, mp), op (mp), q (mp)
    const double *pc, *cov, *means, *op, *q, *cams;
    const float* sh;            // (nk * 3, mp) SH coefficients (row j * 3 + channel), or (3, mp) colours
    int m, mp, nv, width, height, degree, use_shared, tile, tiles_x, tiles_y;
    double near, dilation, radius_sigmas, alpha_threshold, cull_margin;
    float* rec;                 // (nv, m, REC)
    uint8_t* seen;              // (m,)
    // optional (vmask_views, mp) per-view keep mask in depth order: splat k is not drawn in view
    // v < vmask_views where vmask[v mp + k] is 0 (its box written empty, nothing binned)
    const uint8_t* vmask;
    int vmask_views;
};

// view v culls splat k (ProjJob::vmask)
HV_ALWAYS_INLINE inline bool culled(const ProjJob& P, int v, int k) {
    return P.vmask != nullptr && v < P.vmask_views && P.vmask[int64_t(v) * P.mp + k] == 0;
}

// Projection of 8 consecutive splats into one view, written as one loop over the lanes with no
// branches so that the compiler vectorises it (8 doubles per AVX-512 register, 4 per AVX2).
// Same float64 expressions, in the same order, as fast_kernels.project_views (the extension is
// built with -ffp-contract=off, so the results are bit-identical; a test checks).
constexpr int LANES = 8;
struct Block {
    alignas(64) double u[LANES], vv[LANES], A[LANES], B[LANES], C[LANES], col[3][LANES], s[LANES];
    alignas(64) int32_t box[4][LANES];
};

// SLIT: a crossed-slit view (holo_viewer.render.crossed_slit; cams[18] = 1): each centre first
// moves to the column xi = (a X + b Z + c) / (e Z + f) of its eye slice, X' = (xi - cx) Z / fx,
// its covariance by the move's Jacobian (cams[19..23] = a, b, c, e, f), and its SH is seen from
// the camera of that column, position cams[7..9] + s cams[26..28] with s = cams[24] + cams[25] xi
// (the same float64 expressions, in the same order, as crossed_slit's moved splats).
template <int DEG, bool SHARED, bool SLIT>
HV_ALWAYS_INLINE inline void project_block(const ProjJob& P, const double* cam, int k, Block& o) {
    const int64_t mp = P.mp;
    const double fx = cam[0], fy = cam[1], cx = cam[2], cy = cam[3];
    const double d = P.dilation, thr = P.alpha_threshold, near = P.near;
    const bool cull = P.cull_margin >= 0.0;
    const double ulo = -P.cull_margin * P.width, uhi = (1.0 + P.cull_margin) * P.width;
    const double vlo = -P.cull_margin * P.height, vhi = (1.0 + P.cull_margin) * P.height;
    const double* __restrict pc = P.pc + k;
    const double* __restrict cov = P.cov + k;
    const double* __restrict mean = P.means + k;
    const double* __restrict opa = P.op + k;
    const double* __restrict qa = P.q + k;
    const float* __restrict sh = P.sh + k;
#pragma GCC ivdep
    for (int l = 0; l < LANES; ++l) {  // geometry
        const double op = opa[l], q = qa[l];
        double sxx = cov[l], sxy = cov[mp + l], sxz = cov[2 * mp + l];
        const double syy = cov[3 * mp + l], syz = cov[4 * mp + l], szz = cov[5 * mp + l];
        double tx = pc[l] + cam[4], tz = pc[2 * mp + l] + cam[6];
        const double ty = pc[mp + l] + cam[5];
        if (SLIT) {
            const double a = cam[19], b = cam[20], c = cam[21], e = cam[22], f = cam[23];
            const double X = tx, Z = tz, den = e * Z + f;
            const bool ok = den > 1e-9 * Z;
            const double xi = (a * X + b * Z + c) / den;
            const double jx = Z / den * (a / fx);
            const double jz = ((b * f - e * (a * X + c)) / (den * den) * Z + (xi - cx)) / fx;
            const double nxx = jx * jx * sxx + 2.0 * jx * jz * sxz + jz * jz * szz;
            const double nxy = jx * sxy + jz * syz;
            const double nxz = jx * sxz + jz * szz;
            sxx = ok ? nxx : sxx;
            sxy = ok ? nxy : sxy;
            sxz = ok ? nxz : sxz;
            tx = ok ? (xi - cx) * Z / fx : 0.0;
            tz = ok ? tz : -1.0;  // behind the slit camera: not drawn
            o.s[l] = cam[24] + cam[25] * xi;
        }
        const double itz = 1.0 / tz;
        const double u = fx * tx * itz + cx, vv = fy * ty * itz + cy;
        const bool outside = (u < ulo) | (u > uhi) | (vv < vlo) | (vv > vhi);
        const double txc = std::min(std::max(tx * itz, cam[10]), cam[11]) * tz;
        const double tyc = std::min(std::max(ty * itz, cam[12]), cam[13]) * tz;
        const double j00 = fx * itz, j02 = -fx * txc * itz * itz, j11 = fy * itz, j12 = -fy * tyc * itz * itz;
        const double r0x = j00 * sxx + j02 * sxz, r0y = j00 * sxy + j02 * syz, r0z = j00 * sxz + j02 * szz;
        const double r1y = j11 * syy + j12 * syz, r1z = j11 * syz + j12 * szz;
        const double sa = r0x * j00 + r0z * j02, b = r0y * j11 + r0z * j12, sc = r1y * j11 + r1z * j12;
        const double a = sa + d, c = sc + d;
        const double det = std::max(sa * sc - b * b, 0.0) + d * (sa + sc) + d * d;
        const double mid = 0.5 * (a + c);
        const double lam = mid + std::sqrt(std::max(mid * mid - det, 0.0));
        const double rad = std::ceil(P.radius_sigmas * std::sqrt(std::max(lam, 0.0)));
        const double hx = std::min(rad, std::sqrt(q * a) * 1.0001 + 1e-3);
        const double hy = std::min(rad, std::sqrt(q * c) * 1.0001 + 1e-3);
        // the box clipped to the view's pixel rectangle cam[14..17] (the image, or a region of it)
        const double bx0 = std::min(std::max(std::ceil(u - hx - 0.5), cam[14]), cam[15]);
        const double bx1 = std::min(std::max(std::floor(u + hx - 0.5) + 1.0, cam[14]), cam[15]);
        const double by0 = std::min(std::max(std::ceil(vv - hy - 0.5), cam[16]), cam[17]);
        const double by1 = std::min(std::max(std::floor(vv + hy - 0.5) + 1.0, cam[16]), cam[17]);
        // not drawn: an empty box (0, 0, 0, 0), and no NaN reaches the integer conversion
        const bool drawn = (op >= thr) & (tz > near) & !(cull & outside) & (det > 0.0) & (bx0 < bx1) & (by0 < by1);
        o.box[0][l] = int32_t(drawn ? bx0 : 0.0);
        o.box[1][l] = int32_t(drawn ? bx1 : 0.0);
        o.box[2][l] = int32_t(drawn ? by0 : 0.0);
        o.box[3][l] = int32_t(drawn ? by1 : 0.0);
        const double idet = 1.0 / det;
        o.u[l] = u; o.vv[l] = vv;
        o.A[l] = c * idet; o.B[l] = -b * idet; o.C[l] = a * idet;
    }
    if (SHARED) {
        for (int ch = 0; ch < 3; ++ch)
            for (int l = 0; l < LANES; ++l) o.col[ch][l] = sh[ch * mp + l];
        return;
    }
    constexpr int nk = (DEG + 1) * (DEG + 1);
    alignas(64) double bs[nk][LANES];
#pragma GCC ivdep
    for (int l = 0; l < LANES; ++l) {  // SH basis of the view direction
        double x, y, z;
        if (SLIT) {
            x = mean[l] - (cam[7] + o.s[l] * cam[26]);
            y = mean[mp + l] - (cam[8] + o.s[l] * cam[27]);
            z = mean[2 * mp + l] - (cam[9] + o.s[l] * cam[28]);
        } else {
            x = mean[l] - cam[7]; y = mean[mp + l] - cam[8]; z = mean[2 * mp + l] - cam[9];
        }
        const double nrm = std::sqrt(x * x + y * y + z * z);
        const double inv = nrm > 0.0 ? 1.0 / nrm : 1.0;
        x = x * inv; y = y * inv; z = z * inv;
        bs[0][l] = SH_C0;
        if (DEG >= 1) { bs[1][l] = -SH_C1 * y; bs[2][l] = SH_C1 * z; bs[3][l] = -SH_C1 * x; }
        if (DEG >= 2) {
            const double xx = x * x, yy = y * y, zz = z * z, xy = x * y, yz = y * z, xz = x * z;
            bs[4][l] = SH_C2[0] * xy; bs[5][l] = SH_C2[1] * yz; bs[6][l] = SH_C2[2] * (2.0 * zz - xx - yy);
            bs[7][l] = SH_C2[3] * xz; bs[8][l] = SH_C2[4] * (xx - yy);
            if (DEG >= 3) {
                bs[9][l] = SH_C3[0] * y * (3.0 * xx - yy); bs[10][l] = SH_C3[1] * xy * z;
                bs[11][l] = SH_C3[2] * y * (4.0 * zz - xx - yy);
                bs[12][l] = SH_C3[3] * z * (2.0 * zz - 3.0 * xx - 3.0 * yy);
                bs[13][l] = SH_C3[4] * x * (4.0 * zz - xx - yy); bs[14][l] = SH_C3[5] * z * (xx - yy);
                bs[15][l] = SH_C3[6] * x * (xx - 3.0 * yy);
            }
        }
    }
    for (int ch = 0; ch < 3; ++ch) {  // colour = basis . coefficients + 0.5, clamped at 0
        alignas(64) double acc[LANES] = {};
        for (int j = 0; j < nk; ++j) {
            const float* shj = sh + (j * 3 + ch) * mp;
#pragma GCC ivdep
            for (int l = 0; l < LANES; ++l) acc[l] += bs[j][l] * double(shj[l]);
        }
        for (int l = 0; l < LANES; ++l) o.col[ch][l] = std::max(acc[l] + 0.5, 0.0);
    }
}

// band_tiles for the first two tile rows of 8 projected splats, as one vectorisable loop over
// the lanes (same expressions as splat_conic + band_tiles on the record's float32 values, so
// the ranges are identical). Power-of-two tiles only (shift); out: pre[l] = (j0, j1) x 2 rows.
HV_ALWAYS_INLINE inline void band_block(const Block& o, const double* qa, int shift,
                                                      int32_t (*pre)[4]) {
    const int tile = 1 << shift;
    alignas(64) double pj[4][LANES];
#pragma GCC ivdep
    for (int l = 0; l < LANES; ++l) {
        const double u = double(float(o.u[l])), vv = double(float(o.vv[l]));
        const double A = double(float(o.A[l])), Bc = double(float(o.B[l])), C = double(float(o.C[l]));
        const double q = double(float(qa[l]));
        const double det = A * C - Bc * Bc;
        const bool valid = (det > 0.0) & (A > 0.0) & (C > 0.0) & (q > 0.0);
        const double hx = std::sqrt(q * C / det);
        const double iA = 1.0 / A, e = Bc * Bc - A * C, Aq = A * q, kk = Bc * hx / C;
        const int x0 = o.box[0][l], x1 = o.box[1][l], y0 = o.box[2][l], y1 = o.box[3][l];
        const int ty0 = y0 >> shift;
        // the two tile rows written out (a loop inside the lane loop blocks vectorisation)
        auto row = [&](int j, double& out0, double& out1) HV_ALWAYS_INLINE {
            const int ya = std::max(y0, (ty0 + j) << shift), yb = std::min(y1, ((ty0 + j) << shift) + tile) - 1;
            const double d0 = ya + 0.5 - vv, d1 = yb + 0.5 - vv;
            const double dr = std::min(std::max(-kk, d0), d1);
            const double dl = std::min(std::max(kk, d0), d1);
            const double sr = std::sqrt(std::max(dr * dr * e + Aq, 0.0));
            const double sl = std::sqrt(std::max(dl * dl * e + Aq, 0.0));
            const double xr = u + (-Bc * dr + sr * 1.001) * iA + 0.05;
            const double xl = u + (-Bc * dl - sl * 1.001) * iA - 0.05;
            const double cl = std::ceil(xl - 0.5), fr = std::floor(xr - 0.5);
            const double j0 = x0, j1 = x1 - 1;
            const double nj0 = cl > j0 ? (cl > j1 ? j1 + 1.0 : cl) : j0;
            const double use0 = valid ? nj0 : j0;
            const double nj1 = fr < j1 ? (fr < use0 ? use0 - 1.0 : fr) : j1;
            const double use1 = valid ? nj1 : j1;
            // invalid lanes and rows past the box give unused values; keep them finite
            out0 = use0 == use0 ? use0 : 0.0;
            out1 = use1 == use1 ? use1 : 0.0;
        };
        row(0, pj[0][l], pj[1][l]);
        row(1, pj[2][l], pj[3][l]);
    }
    for (int l = 0; l < LANES; ++l)
        for (int i = 0; i < 4; ++i) pre[l][i] = int32_t(std::min(std::max(pj[i][l], -1.0), 1e9));
}

// The (splat, tile) entries of one work unit in depth order, k in the low and t in the high 32
// bits: the fill scatters them in one flat loop (replaying the band ranges splat by splat, as
// it did before, was 2.7x slower, measured). A growable buffer whose free room can be written
// ahead of its size (bin_splat writes up to four candidate entries and keeps the valid ones);
// its storage is left uninitialised, as std::vector's reserved capacity is.
struct Entries {
    std::unique_ptr<uint64_t[]> buf;
    size_t n = 0, cap = 0;
    void grow(size_t c) {
        std::unique_ptr<uint64_t[]> b(new uint64_t[c]);
        if (n) std::memcpy(b.get(), buf.get(), n * sizeof(uint64_t));
        buf = std::move(b);
        cap = c;
    }
    void clear() { n = 0; }
    void reserve(size_t c) { if (cap < c) grow(c); }
    uint64_t* room(size_t k) {  // at least k writable entries at data() + size()
        if (n + k > cap) grow(std::max(cap * 2, n + k + 1024));
        return buf.get() + n;
    }
    void push_back(uint64_t e) { *room(1) = e; ++n; }
    const uint64_t* data() const { return buf.get(); }
    size_t size() const { return n; }
    size_t capacity() const { return cap; }
};

inline uint64_t entry(int k, int t) { return uint64_t(uint32_t(k)) | (uint64_t(uint32_t(t)) << 32); }

// The entries of splat k (box = its record's pixel box, drawn) in view v: entries_of's tiles in
// its order. A splat whose box spans at most 2 x 2 tiles (most of an avatar's: they are a few
// pixels wide) takes a branch-free path: its four candidate tiles written, the ones entries_of
// lists kept (the same tiles in the same order, without entries_of's data-dependent loops:
// projection pass 132 -> 124 ms per avatar quilt, measured A/B in one process).
HV_ALWAYS_INLINE inline void bin_splat(const BinJob& B, int v, int k, const int32_t* box, const int32_t* pre,
                                       int64_t* cnt, Entries& ent) {
    const int sh = B.div.shift;
    const int x0 = box[0], x1 = box[1], y0 = box[2], y1 = box[3];
    if (pre && x0 >= 0 && y0 >= 0 && int64_t(x1) <= int64_t(B.tiles_x) << sh &&
        int64_t(y1) <= int64_t(B.tiles_y) << sh) {
        const int tx0 = x0 >> sh, tx1 = (x1 - 1) >> sh, ty0 = y0 >> sh, ty1 = (y1 - 1) >> sh;
        if (tx1 - tx0 <= 1 && ty1 - ty0 <= 1) {
            // per tile row r: the tile columns [a_r, b_r] entries_of lists (one column: all of it)
            const bool one = tx0 == tx1;
            int a[2], b[2];
            for (int r = 0; r < 2; ++r) {
                const int j0 = pre[2 * r], j1 = pre[2 * r + 1];
                const bool empty = j0 > j1;
                a[r] = one ? tx0 : empty ? 1 : j0 >> sh;
                b[r] = one ? tx0 : empty ? 0 : j1 >> sh;
            }
            // ranges reaching past the box's two columns (never, by band_block's clipping) go the long way
            if (one || ((a[0] > b[0] || (a[0] >= tx0 && b[0] <= tx1)) &&
                        (ty0 == ty1 || a[1] > b[1] || (a[1] >= tx0 && b[1] <= tx1)))) {
                uint64_t* out = ent.room(4);
                int n = 0;
                for (int r = 0; r < 2; ++r) {
                    const int ty = ty0 + r;
                    const bool row = r == 0 || ty1 > ty0;
                    for (int c = 0; c < 2; ++c) {
                        const int tx = tx0 + c;
                        const bool in = row & (a[r] <= tx) & (tx <= b[r]);
                        const int t = ty * B.tiles_x + tx;
                        out[n] = entry(k, t);
                        n += in;
                        cnt[t] += in;  // t < nt + tiles_x + 1: the counts are padded (see project_bin)
                    }
                }
                ent.n += size_t(n);
                return;
            }
        }
    }
    entries_of(B, v, k, pre, [&](int kk, int t) {
        ++cnt[t];
        ent.push_back(entry(kk, t));
    });
}

// One work unit of project_bin: splats [k0, k1) of view v, projected 8 at a time, each drawn
// one binned at once: entries counted per tile and appended to ent. Compiled once per
// instruction set.
// Inputs of up to LANES splats gathered from scattered indices, in the layout of ProjJob with
// row stride LANES (project_block reads it through a ProjJob whose pointers are set here).
struct Gathered {
    alignas(64) double pc[3][LANES], cov[6][LANES], means[3][LANES], op[LANES], q[LANES];
    alignas(64) float sh[48][LANES];
};

// Writes the record of splat k (lane l of o) into view v and bins it (as project_count).
HV_ALWAYS_INLINE inline void emit(const ProjJob& P, const BinJob& B, int v, int k, const Block& o, int l,
                                  const int32_t* pre, int64_t* cnt, Entries& ent) {
    float* r = P.rec + (int64_t(v) * P.m + k) * REC;
    int32_t box[4] = {o.box[0][l], o.box[1][l], o.box[2][l], o.box[3][l]};
    if (culled(P, v, k)) box[1] = box[0];
    std::memcpy(r + BOX_AT, box, sizeof(box));
    if (box[0] >= box[1] || box[2] >= box[3]) return;
    r[0] = float(o.u[l]); r[1] = float(o.vv[l]);
    r[2] = float(o.A[l]); r[3] = float(o.B[l]); r[4] = float(o.C[l]);
    r[5] = float(P.op[k]);
    r[6] = float(o.col[0][l]); r[7] = float(o.col[1][l]); r[8] = float(o.col[2][l]);
    r[9] = float(P.q[k]);
    reinterpret_cast<std::atomic<uint8_t>*>(P.seen + k)->store(1, std::memory_order_relaxed);
    bin_splat(B, v, k, box, pre, cnt, ent);
}

// project_count for a view restricted to a pixel rectangle (cam[14..17] smaller than the image):
// a cheap conservative test first keeps the splats whose box can reach the rectangle, which are
// then projected by the same project_block, 8 at a time (identical records). The
// test bounds the box half-widths from the projected covariance's diagonal (a, c: the same
// expressions as project_block, no conic, colour or record): hx = min(rad, sqrt(q a) 1.0001 +
// 1e-3) with rad <= rs sqrt(lambda_max) + 1 and lambda_max <= a + c (the trace), same for hy;
// the rectangle is widened by 2 px against rounding. A kept splat may still not be drawn.
template <int DEG, bool SHARED>
HV_ALWAYS_INLINE inline void project_count_region(const ProjJob& P, const BinJob& B, int v, int k0, int k1,
                                                  int64_t* cnt, Entries& ent) {
    const double* cam = P.cams + int64_t(v) * CAM;
    const int64_t mp = P.mp;
    const double fx = cam[0], fy = cam[1], cx = cam[2], cy = cam[3];
    const double xlo = cam[14] - 2.0, xhi = cam[15] + 2.0, ylo = cam[16] - 2.0, yhi = cam[17] + 2.0;
    const double rs2 = P.radius_sigmas * P.radius_sigmas * (1.0 + 1e-6), d = P.dilation;
    const double thr = P.alpha_threshold, near = P.near;
    const double ox = cam[4], oy = cam[5], oz = cam[6], lx0 = cam[10], lx1 = cam[11], ly0 = cam[12], ly1 = cam[13];
    constexpr int SPAN = 8 * LANES;
    alignas(64) int32_t keep[SPAN];  // not char: a char store may alias the inputs and block vectorisation
    const double* __restrict pcx = P.pc;
    const double* __restrict cv = P.cov;
    const double* __restrict opa = P.op;
    const double* __restrict qa = P.q;
    Block o;
    alignas(64) int32_t pre[LANES][4];
    const bool banded = B.div.shift >= 0;
    constexpr int DENSE = 3;  // kept splats in a block of 8 from which it is projected in place
    const int nrows = SHARED ? 3 : (DEG + 1) * (DEG + 1) * 3;
    int32_t idx[LANES];
    int np_ = 0;
    Gathered g;
    ProjJob Pl = P;
    Pl.pc = &g.pc[0][0]; Pl.cov = &g.cov[0][0]; Pl.means = &g.means[0][0]; Pl.op = g.op; Pl.q = g.q;
    Pl.sh = &g.sh[0][0]; Pl.mp = LANES;
    auto flush = [&]() {
        if (np_ == 0) return;
        for (int l = 0; l < LANES; ++l) {  // unused lanes repeat the first splat with opacity 0
            const int k = idx[l < np_ ? l : 0];
            for (int i = 0; i < 3; ++i) g.pc[i][l] = P.pc[i * mp + k];
            for (int i = 0; i < 6; ++i) g.cov[i][l] = P.cov[i * mp + k];
            for (int i = 0; i < 3; ++i) g.means[i][l] = P.means[i * mp + k];
            g.op[l] = l < np_ ? P.op[k] : 0.0;
            g.q[l] = P.q[k];
            for (int i = 0; i < nrows; ++i) g.sh[i][l] = P.sh[i * mp + k];
        }
        project_block<DEG, SHARED, false>(Pl, cam, 0, o);
        if (banded) band_block(o, g.q, B.div.shift, pre);
        for (int l = 0; l < np_; ++l) emit(P, B, v, idx[l], o, l, banded ? pre[l] : nullptr, cnt, ent);
        np_ = 0;
    };
    for (int ks = k0; ks < k1; ks += SPAN) {
        const int n = std::min(SPAN, k1 - ks);
#pragma GCC ivdep
        for (int l = 0; l < n; ++l) {
            const int k = ks + l;
            const double tx = pcx[k] + ox, ty = pcx[mp + k] + oy, tz = pcx[2 * mp + k] + oz;
            const double itz = 1.0 / tz;
            const double u = fx * tx * itz + cx, vv = fy * ty * itz + cy;
            // the projected covariance's diagonal, as project_block computes it
            const double sxx = cv[k], sxz = cv[2 * mp + k];
            const double syy = cv[3 * mp + k], syz = cv[4 * mp + k], szz = cv[5 * mp + k];
            const double txc = std::min(std::max(tx * itz, lx0), lx1) * tz;
            const double tyc = std::min(std::max(ty * itz, ly0), ly1) * tz;
            const double j00 = fx * itz, j02 = -fx * txc * itz * itz, j11 = fy * itz, j12 = -fy * tyc * itz * itz;
            const double sa = (j00 * sxx + j02 * sxz) * j00 + (j00 * sxz + j02 * szz) * j02;
            const double sc = (j11 * syy + j12 * syz) * j11 + (j11 * syz + j12 * szz) * j12;
            const double a = sa + d, c = sc + d, q = qa[k];
            // hx = min(rad, sqrt(q a) 1.0001 + 1e-3) with rad <= rs sqrt(lambda_max) + 1, lambda_max <= a + c
            const double rad = std::sqrt(rs2 * std::max(a + c, 0.0)) + 1.0;
            const double hx = std::min(rad, std::sqrt(std::max(q * a, 0.0)) * 1.0001 + 1e-3) + 1e-6 * std::abs(u);
            const double hy = std::min(rad, std::sqrt(std::max(q * c, 0.0)) * 1.0001 + 1e-3) + 1e-6 * std::abs(vv);
            keep[l] = int32_t((opa[k] >= thr) & (tz > near) & (u - hx < xhi) & (u + hx > xlo) & (vv - hy < yhi) &
                              (vv + hy > ylo));
        }
        // blocks of 8 with several kept splats go through project_block where they lie (sequential
        // reads); single kept splats are gathered into blocks of 8 first
        for (int b0 = 0; b0 < n; b0 += LANES) {
            int cnt8 = 0;
            for (int l = b0; l < b0 + LANES; ++l) cnt8 += l < n ? keep[l] : 0;
            if (cnt8 == 0) continue;
            if (cnt8 >= DENSE) {
                flush();  // the pending gathered splats come first: the lists stay in depth order
                project_block<DEG, SHARED, false>(P, cam, ks + b0, o);
                if (banded) band_block(o, P.q + ks + b0, B.div.shift, pre);
                for (int l = 0; l < LANES && b0 + l < n; ++l)
                    if (keep[b0 + l]) emit(P, B, v, ks + b0 + l, o, l, banded ? pre[l] : nullptr, cnt, ent);
                continue;
            }
            for (int l = b0; l < b0 + LANES && l < n; ++l)
                if (keep[l]) {
                    idx[np_++] = ks + l;
                    if (np_ == LANES) flush();
                }
        }
    }
    flush();
}

template <int DEG, bool SHARED, bool SLIT>
HV_ALWAYS_INLINE inline void project_count(const ProjJob& P, const BinJob& B, int v, int k0, int k1,
                                                         int64_t* cnt, Entries& ent) {
    const double* cam = P.cams + int64_t(v) * CAM;
    if (!SLIT && (cam[14] > 0.0 || cam[15] < P.width || cam[16] > 0.0 || cam[17] < P.height))
        return project_count_region<DEG, SHARED>(P, B, v, k0, k1, cnt, ent);
    Block o;
    alignas(64) int32_t pre[LANES][4];
    const bool banded = B.div.shift >= 0;
    for (int k = k0; k < k1; k += LANES) {
        project_block<DEG, SHARED, SLIT>(P, cam, k, o);
        if (banded) band_block(o, P.q + k, B.div.shift, pre);
        const int n = std::min(LANES, k1 - k);
        for (int l = 0; l < n; ++l) {
            float* r = P.rec + (int64_t(v) * P.m + k + l) * REC;
            int32_t box[4] = {o.box[0][l], o.box[1][l], o.box[2][l], o.box[3][l]};
            if (culled(P, v, k + l)) box[1] = box[0];
            std::memcpy(r + BOX_AT, box, sizeof(box));
            if (box[0] >= box[1] || box[2] >= box[3]) continue;
            r[0] = float(o.u[l]); r[1] = float(o.vv[l]);
            r[2] = float(o.A[l]); r[3] = float(o.B[l]); r[4] = float(o.C[l]);
            r[5] = float(P.op[k + l]);
            r[6] = float(o.col[0][l]); r[7] = float(o.col[1][l]); r[8] = float(o.col[2][l]);
            r[9] = float(P.q[k + l]);
            reinterpret_cast<std::atomic<uint8_t>*>(P.seen + k + l)->store(1, std::memory_order_relaxed);
            bin_splat(B, v, k + l, box, banded ? pre[l] : nullptr, cnt, ent);
        }
    }
}

using CountFn = void (*)(const ProjJob&, const BinJob&, int, int, int, int64_t*, Entries&);

#define HV_COUNT_VARIANT(NAME, ATTR)                                                                        \
    template <int DEG, bool SHARED, bool SLIT>                                                              \
    ATTR void NAME(const ProjJob& P, const BinJob& B, int v, int k0, int k1, int64_t* cnt,                 \
                   Entries& ent) {                                                                          \
        project_count<DEG, SHARED, SLIT>(P, B, v, k0, k1, cnt, ent);                                       \
    }
HV_COUNT_VARIANT(count_generic, )
#if HV_HAVE_AVX2_PATH
HV_COUNT_VARIANT(count_avx2, __attribute__((target("avx2,fma,sse4.1"))))
HV_COUNT_VARIANT(count_avx512, __attribute__((target("avx512f,avx512vl,avx512dq,avx2,fma,sse4.1"))))
#endif

template <template <int, bool, bool> class Sel, bool SLIT>
CountFn pick_degree(int degree, bool shared) {
    if (shared) return Sel<0, true, SLIT>::fn;
    switch (degree) {
        case 0: return Sel<0, false, SLIT>::fn;
        case 1: return Sel<1, false, SLIT>::fn;
        case 2: return Sel<2, false, SLIT>::fn;
        default: return Sel<3, false, SLIT>::fn;
    }
}
template <int D, bool S, bool L> struct SelGeneric { static constexpr CountFn fn = count_generic<D, S, L>; };
#if HV_HAVE_AVX2_PATH
template <int D, bool S, bool L> struct SelAvx2 { static constexpr CountFn fn = count_avx2<D, S, L>; };
template <int D, bool S, bool L> struct SelAvx512 { static constexpr CountFn fn = count_avx512<D, S, L>; };
#endif

template <bool SLIT>
CountFn count_function(int degree, bool shared) {
#if HV_HAVE_AVX2_PATH
    if (cpu_has_avx512()) return pick_degree<SelAvx512, SLIT>(degree, shared);
    if (cpu_has_avx2()) return pick_degree<SelAvx2, SLIT>(degree, shared);
#endif
    return pick_degree<SelGeneric, SLIT>(degree, shared);
}

// project_bin's per-unit tile counts and (splat, tile) entries (~45 MB for the avatar quilt's
// chunks of 11 views of 100k splats), kept between calls: fresh memory for them was
// page-faulted thousands of times per call, ~20 % of the count pass (measured). A call that
// finds the cache in use by another thread uses its own.
struct BinScratch {
    std::vector<std::vector<int64_t>> counts;
    std::vector<Entries> entries;
    std::vector<int64_t> cursor;
    size_t bytes() const {
        size_t n = cursor.capacity() * sizeof(int64_t);
        for (const auto& c : counts) n += c.capacity() * sizeof(int64_t);
        for (const auto& e : entries) n += e.capacity() * sizeof(uint64_t);
        return n;
    }
};
std::mutex bin_scratch_mutex;
BinScratch bin_scratch;
constexpr size_t BIN_SCRATCH_KEEP = size_t(256) << 20;  // a larger scratch is freed after the call

PyObject* project_bin(PyObject*, PyObject* args) {
    Py_buffer pc{}, cov{}, means{}, op{}, q{}, sh{}, cams{}, rec{}, off{}, base{}, seen{}, ids{}, vmask{};
    ProjJob P{};
    int n_threads;
    P.vmask_views = 0;
    if (!PyArg_ParseTuple(args, "y*y*y*y*y*y*y*iiiiiiiiiidddddw*w*w*w*w*i|y*i", &pc, &cov, &means, &op, &q, &sh, &cams,
                          &P.m, &P.mp, &P.nv, &P.width, &P.height, &P.degree, &P.use_shared, &P.tile, &P.tiles_x,
                          &P.tiles_y, &P.near, &P.dilation, &P.radius_sigmas, &P.alpha_threshold, &P.cull_margin,
                          &rec, &off, &base, &seen, &ids, &n_threads, &vmask, &P.vmask_views))
        return nullptr;
    PyObject* result = nullptr;
    const int64_t nt = int64_t(P.tiles_x) * P.tiles_y;
    const int nk = P.use_shared ? 1 : (P.degree + 1) * (P.degree + 1);
    bool ok = P.nv > 0 && P.m >= 0 && P.mp >= P.m && P.mp % LANES == 0 && P.tile > 0 && P.tiles_x > 0 && P.tiles_y > 0 && P.width > 0 &&
              P.height > 0 && int64_t(P.tiles_x) * P.tile >= P.width && int64_t(P.tiles_y) * P.tile >= P.height &&
              P.degree >= 0 && P.degree <= 3;
    if (!ok) PyErr_SetString(PyExc_ValueError, "_splat_cpp.project_bin: inconsistent sizes");
    const Py_ssize_t m = P.m, mp = P.mp;
    ok = ok && need(pc, mp * 24, "pc") && need(cov, mp * 48, "cov") && need(means, mp * 24, "means") &&
         need(op, mp * 8, "opacity") && need(q, mp * 8, "q") && need(sh, mp * nk * 12, "sh") &&
         need(cams, Py_ssize_t(P.nv) * CAM * 8, "cams") && need(rec, Py_ssize_t(P.nv) * m * REC * 4, "rec") &&
         need(off, Py_ssize_t(P.nv) * (nt + 1) * 8, "off") && need(base, Py_ssize_t(P.nv) * 8, "base") &&
         need(seen, m, "seen");
    ok = ok && (P.vmask_views >= 0 && P.vmask_views <= P.nv);
    if (!ok && !PyErr_Occurred()) PyErr_SetString(PyExc_ValueError, "_splat_cpp.project_bin: vmask_views outside 0 .. nv");
    ok = ok && (P.vmask_views == 0 || need(vmask, Py_ssize_t(P.vmask_views) * mp, "vmask"));
    if (ok) {
        P.vmask = P.vmask_views > 0 ? (const uint8_t*)vmask.buf : nullptr;
        P.pc = (const double*)pc.buf; P.cov = (const double*)cov.buf; P.means = (const double*)means.buf;
        P.op = (const double*)op.buf; P.q = (const double*)q.buf; P.cams = (const double*)cams.buf;
        P.sh = (const float*)sh.buf; P.rec = (float*)rec.buf; P.seen = (uint8_t*)seen.buf;
        std::memset(P.seen, 0, size_t(m));
        n_threads = std::max(1, n_threads);
        // segments of the splat range: work units of the count pass (each projects its splats
        // into every view, a block at a time, so the block's inputs are read from memory once
        // for all the views instead of once per view), enough to keep every thread busy
        const int segs = std::max(1, std::min<int>(2 * n_threads, std::max(1, P.m / 4096)));
        const int n_units = P.nv * segs;
        std::unique_lock<std::mutex> cached(bin_scratch_mutex, std::try_to_lock);
        BinScratch own;
        BinScratch& scratch = cached.owns_lock() ? bin_scratch : own;
        auto& counts = scratch.counts;  // per unit: entries per tile
        auto& entries = scratch.entries;  // per unit: its (splat, tile) entries, for the fill
        if (counts.size() < size_t(n_units)) counts.resize(size_t(n_units));
        if (entries.size() < size_t(n_units)) entries.resize(size_t(n_units));
        const CountFn count_pin = count_function<false>(P.degree, P.use_shared != 0);
        const CountFn count_slit = count_function<true>(P.degree, P.use_shared != 0);
        std::atomic<bool> bad{false};
        BinJob B{P.rec, P.m, P.tile, P.tiles_x, P.tiles_y, &bad, TileDiv(P.tile)};
        auto seg_range = [&](int s, int& k0, int& k1) {  // multiples of LANES (blocks read k..k+7)
            k0 = int(int64_t(P.m) * s / segs) & ~(LANES - 1);
            k1 = s + 1 == segs ? P.m : int(int64_t(P.m) * (s + 1) / segs) & ~(LANES - 1);
        };
        Py_BEGIN_ALLOW_THREADS
        parallel_for(segs, n_threads, [&](int s) {
            int k0, k1;
            seg_range(s, k0, k1);
            for (int v = 0; v < P.nv; ++v) {
                const int unit = v * segs + s;
                // padded by a tile row + 1: bin_splat adds 0 to the counter of each of its four candidate
                // tiles that it does not list, off the grid too (beside it or below it), instead of to
                // one dummy counter: a chain of store-to-load forwarding through that counter from
                // splat to splat took ~3 % of the count pass (measured A/B on live frames)
                counts[unit].assign(size_t(nt + P.tiles_x + 1), 0);
                entries[unit].clear();
                entries[unit].reserve(size_t(k1 - k0) * 5);
            }
            constexpr int BLOCK = 8 * LANES;  // splats per view in turn
            for (int kb = k0; kb < k1; kb += BLOCK)
                for (int v = 0; v < P.nv; ++v) {
                    const int unit = v * segs + s;
                    (P.cams[int64_t(v) * CAM + 18] != 0.0 ? count_slit : count_pin)(
                        P, B, v, kb, std::min(k1, kb + BLOCK), counts[unit].data(), entries[unit]);
                }
        });
        Py_END_ALLOW_THREADS
        int64_t* offp = (int64_t*)off.buf;
        int64_t* basep = (int64_t*)base.buf;
        int64_t total = 0;
        std::vector<int64_t>& cursor = scratch.cursor;
        cursor.assign(size_t(n_units) * nt, 0);
        for (int v = 0; v < P.nv; ++v) {
            basep[v] = total;
            int64_t* o = offp + int64_t(v) * (nt + 1);
            int64_t run = 0;
            for (int64_t t = 0; t < nt; ++t) {
                o[t] = run;
                for (int s = 0; s < segs; ++s) {
                    cursor[size_t(v * segs + s) * nt + t] = run;
                    run += counts[v * segs + s][t];
                }
            }
            o[nt] = run;
            total += run;
        }
        if (bad.load()) {
            PyErr_SetString(PyExc_ValueError, "_splat_cpp.project_bin: a splat box lies outside the tile grid");
        } else if (total * 4 > ids.len) {
            result = Py_BuildValue("Ld", (long long)total, 0.0);  // caller grows ids and calls again
        } else {
            const auto t_fill = std::chrono::steady_clock::now();
            int32_t* idsp = (int32_t*)ids.buf;
            Py_BEGIN_ALLOW_THREADS
            parallel_for(n_units, n_threads, [&](int unit) {  // one flat loop: no branch per splat
                int64_t* cur = cursor.data() + size_t(unit) * nt;
                int32_t* out = idsp + basep[unit / segs];
                const uint64_t* e = entries[unit].data();
                const size_t n = entries[unit].size();
                for (size_t i = 0; i < n; ++i) out[cur[e[i] >> 32]++] = int32_t(uint32_t(e[i]));
            });
            Py_END_ALLOW_THREADS
            const double fill_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t_fill).count();
            result = Py_BuildValue("Ld", (long long)total, fill_s);
        }
        if (scratch.bytes() > BIN_SCRATCH_KEEP) scratch = BinScratch();
    }
    PyBuffer_Release(&pc); PyBuffer_Release(&cov); PyBuffer_Release(&means); PyBuffer_Release(&op);
    PyBuffer_Release(&q); PyBuffer_Release(&sh); PyBuffer_Release(&cams); PyBuffer_Release(&rec);
    PyBuffer_Release(&off); PyBuffer_Release(&base); PyBuffer_Release(&seen); PyBuffer_Release(&ids);
    if (vmask.obj != nullptr) PyBuffer_Release(&vmask);
    return result;
}

// ---- fast_kernels.prep_sorted: the depth-ordered inputs of project_bin in one pass (same float64
// expressions in the same order, std::exp = libm exp as numba's math.exp: bit-identical; tested)
constexpr int PREP_AHEAD = 16;  // splats
template <typename T>
void prep_sorted_rows(const int64_t* ord, const T* M, const T* Q, const T* L, const double* O, const float* C,
                      const double* W, double* PC, double* CV, double* MO, double* OP, float* SH, int m, int mp, int c,
                      int i0, int i1) {
    for (int i = i0; i < i1; ++i) {
        if (i >= m) {
            for (int r = 0; r < 3; ++r) { PC[r * mp + i] = 0.0; MO[r * mp + i] = 0.0; }
            for (int r = 0; r < 6; ++r) CV[r * mp + i] = 0.0;
            OP[i] = 0.0;
            for (int j = 0; j < c; ++j) SH[int64_t(j) * mp + i] = 0.0f;
            continue;
        }
        if (i + PREP_AHEAD < m) {  // the order jumps about: fetch a later splat's inputs now
            const int64_t kf = ord[i + PREP_AHEAD];
            __builtin_prefetch(Q + 4 * kf); __builtin_prefetch(M + 3 * kf); __builtin_prefetch(L + 3 * kf);
            __builtin_prefetch(O + kf); __builtin_prefetch(C + kf * c);
            if (c * 4 > 64) __builtin_prefetch(C + kf * c + 16);
        }
        const int64_t k = ord[i];  // inputs widened to double exactly, as the numba path's copies
        double w = double(Q[4 * k]), x = double(Q[4 * k + 1]), y = double(Q[4 * k + 2]), z = double(Q[4 * k + 3]);
        const double qn = std::sqrt(w * w + x * x + y * y + z * z);
        w = w / qn; x = x / qn; y = y / qn; z = z / qn;
        const double R00 = 1 - 2 * (y * y + z * z), R01 = 2 * (x * y - w * z), R02 = 2 * (x * z + w * y);
        const double R10 = 2 * (x * y + w * z), R11 = 1 - 2 * (x * x + z * z), R12 = 2 * (y * z - w * x);
        const double R20 = 2 * (x * z - w * y), R21 = 2 * (y * z + w * x), R22 = 1 - 2 * (x * x + y * y);
        const double s0 = std::exp(double(L[3 * k])), s1 = std::exp(double(L[3 * k + 1])),
                     s2 = std::exp(double(L[3 * k + 2]));
        const double m0 = double(M[3 * k]), m1 = double(M[3 * k + 1]), m2 = double(M[3 * k + 2]);
        double Mx[3][3];
        for (int r = 0; r < 3; ++r) {
            const double a0 = W[3 * r] * R00 + W[3 * r + 1] * R10 + W[3 * r + 2] * R20;
            const double a1 = W[3 * r] * R01 + W[3 * r + 1] * R11 + W[3 * r + 2] * R21;
            const double a2 = W[3 * r] * R02 + W[3 * r + 1] * R12 + W[3 * r + 2] * R22;
            Mx[r][0] = a0 * s0; Mx[r][1] = a1 * s1; Mx[r][2] = a2 * s2;
            PC[r * mp + i] = W[3 * r] * m0 + W[3 * r + 1] * m1 + W[3 * r + 2] * m2;
        }
        CV[i] = Mx[0][0] * Mx[0][0] + Mx[0][1] * Mx[0][1] + Mx[0][2] * Mx[0][2];
        CV[mp + i] = Mx[0][0] * Mx[1][0] + Mx[0][1] * Mx[1][1] + Mx[0][2] * Mx[1][2];
        CV[2 * mp + i] = Mx[0][0] * Mx[2][0] + Mx[0][1] * Mx[2][1] + Mx[0][2] * Mx[2][2];
        CV[3 * mp + i] = Mx[1][0] * Mx[1][0] + Mx[1][1] * Mx[1][1] + Mx[1][2] * Mx[1][2];
        CV[4 * mp + i] = Mx[1][0] * Mx[2][0] + Mx[1][1] * Mx[2][1] + Mx[1][2] * Mx[2][2];
        CV[5 * mp + i] = Mx[2][0] * Mx[2][0] + Mx[2][1] * Mx[2][1] + Mx[2][2] * Mx[2][2];
        MO[i] = m0; MO[mp + i] = m1; MO[2 * mp + i] = m2;
        OP[i] = O[k];
        for (int j = 0; j < c; ++j) SH[int64_t(j) * mp + i] = C[k * c + j];
    }
}

PyObject* prep_sorted(PyObject*, PyObject* args) {
    Py_buffer order{}, means{}, quats{}, ls{}, opa{}, col{}, rot{}, pc{}, cov{}, mout{}, op{}, sh{};
    int m, mp, n, c, n_threads, f32;
    if (!PyArg_ParseTuple(args, "y*y*y*y*y*y*y*w*w*w*w*w*iiiiii", &order, &means, &quats, &ls, &opa, &col, &rot, &pc,
                          &cov, &mout, &op, &sh, &m, &mp, &n, &c, &f32, &n_threads))
        return nullptr;
    const int64_t fs = f32 ? 4 : 8;  // bytes of a means / quats / log_scales value
    bool ok = m >= 0 && mp >= m && n >= 0 && c >= 0;
    if (!ok) PyErr_SetString(PyExc_ValueError, "_splat_cpp.prep_sorted: inconsistent sizes");
    ok = ok && need(order, int64_t(m) * 8, "order") && need(means, int64_t(n) * 3 * fs, "means") &&
         need(quats, int64_t(n) * 4 * fs, "quats") && need(ls, int64_t(n) * 3 * fs, "log_scales") &&
         need(opa, int64_t(n) * 8, "opacity") && need(col, int64_t(n) * c * 4, "colours") && need(rot, 72, "Wrot") &&
         need(pc, int64_t(mp) * 24, "pc") && need(cov, int64_t(mp) * 48, "cov") && need(mout, int64_t(mp) * 24, "mout") &&
         need(op, int64_t(mp) * 8, "op") && need(sh, int64_t(mp) * c * 4, "sh");
    const int64_t* ord = (const int64_t*)order.buf;
    for (int i = 0; ok && i < m; ++i) ok = ord[i] >= 0 && ord[i] < n;
    if (!ok && !PyErr_Occurred()) PyErr_SetString(PyExc_ValueError, "_splat_cpp.prep_sorted: order outside 0 .. N");
    if (ok) {
        const int chunk = 2048;
        Py_BEGIN_ALLOW_THREADS
        parallel_for((mp + chunk - 1) / chunk, std::max(1, n_threads), [&](int ci) {
            const int i0 = ci * chunk, i1 = std::min(mp, ci * chunk + chunk);
            if (f32)
                prep_sorted_rows<float>(ord, (const float*)means.buf, (const float*)quats.buf, (const float*)ls.buf,
                                        (const double*)opa.buf, (const float*)col.buf, (const double*)rot.buf,
                                        (double*)pc.buf, (double*)cov.buf, (double*)mout.buf, (double*)op.buf,
                                        (float*)sh.buf, m, mp, c, i0, i1);
            else
                prep_sorted_rows<double>(ord, (const double*)means.buf, (const double*)quats.buf, (const double*)ls.buf,
                                         (const double*)opa.buf, (const float*)col.buf, (const double*)rot.buf,
                                         (double*)pc.buf, (double*)cov.buf, (double*)mout.buf, (double*)op.buf,
                                         (float*)sh.buf, m, mp, c, i0, i1);
        });
        Py_END_ALLOW_THREADS
    }
    PyBuffer_Release(&order); PyBuffer_Release(&means); PyBuffer_Release(&quats); PyBuffer_Release(&ls);
    PyBuffer_Release(&opa); PyBuffer_Release(&col); PyBuffer_Release(&rot); PyBuffer_Release(&pc);
    PyBuffer_Release(&cov); PyBuffer_Release(&mout); PyBuffer_Release(&op); PyBuffer_Release(&sh);
    if (!ok) return nullptr;
    Py_RETURN_NONE;
}

// ---- fast.depth_order: a stable argsort of float64 depths (numpy's argsort(kind="stable"),
// identical: ties keep index order). LSD radix sort, 11 bits a pass, on the depths' bits mapped
// to order-preserving unsigned keys (-0.0 and +0.0, which compare equal, mapped to one key; NaN
// of either sign last, as numpy puts it); the passes whose digit is the same for every key are
// skipped. 1.3 ms against 3.9 ms for the hinted timsort on 100k depths of an animated avatar
// (where the previous frame's order is a poor hint), 2.0 against 10 ms unhinted.
PyObject* argsort_stable(PyObject*, PyObject* args) {
    Py_buffer zb{}, ob{};
    if (!PyArg_ParseTuple(args, "y*w*", &zb, &ob)) return nullptr;
    const int64_t n = zb.len / 8;
    bool ok = zb.len % 8 == 0 && need(ob, n * 8, "order");
    if (ok && zb.len == 0) { PyBuffer_Release(&zb); PyBuffer_Release(&ob); Py_RETURN_NONE; }
    if (ok) {
        const double* z = (const double*)zb.buf;
        int64_t* out = (int64_t*)ob.buf;
        constexpr int BITS = 11, PASSES = (64 + BITS - 1) / BITS, B = 1 << BITS;
        Py_BEGIN_ALLOW_THREADS
        static thread_local std::vector<uint64_t> ka, kb;  // kept between calls (no page faults)
        static thread_local std::vector<int64_t> ib;
        if (ka.size() < size_t(n) || ka.size() > 4 * size_t(n) + 4096) {
            ka.assign(size_t(n), 0); kb.assign(size_t(n), 0); ib.assign(size_t(n), 0);
        }
        std::vector<int64_t> hist(size_t(PASSES) * B, 0);
        for (int64_t i = 0; i < n; ++i) {
            double v = z[i];
            v = v == 0.0 ? 0.0 : v;  // -0.0 == +0.0
            uint64_t b;
            std::memcpy(&b, &v, 8);
            b = (b >> 63) ? ~b : (b | (uint64_t(1) << 63));
            b = v == v ? b : ~uint64_t(0);  // NaN (of either sign) last, as numpy sorts it
            ka[size_t(i)] = b;
            for (int p = 0; p < PASSES; ++p) ++hist[size_t(p) * B + ((b >> (p * BITS)) & (B - 1))];
            out[i] = i;
        }
        uint64_t* kin = ka.data();
        uint64_t* kout = kb.data();
        int64_t* iin = out;
        int64_t* iout = ib.data();
        for (int p = 0; p < PASSES; ++p) {
            int64_t* h = hist.data() + size_t(p) * B;
            bool trivial = false;
            for (int d = 0; d < B; ++d)
                if (h[d] != 0) { trivial = h[d] == n; break; }
            if (trivial) continue;  // one digit for all: the order stays
            int64_t run = 0;
            for (int d = 0; d < B; ++d) { const int64_t c = h[d]; h[d] = run; run += c; }
            const int shift = p * BITS;
            for (int64_t i = 0; i < n; ++i) {
                const uint64_t k = kin[i];
                const int64_t at = h[(k >> shift) & (B - 1)]++;
                kout[at] = k;
                iout[at] = iin[i];
            }
            std::swap(kin, kout);
            std::swap(iin, iout);
        }
        if (iin != out) std::memcpy(out, iin, size_t(n) * 8);
        Py_END_ALLOW_THREADS
    } else if (!PyErr_Occurred()) {
        PyErr_SetString(PyExc_ValueError, "_splat_cpp.argsort_stable: z must be float64");
    }
    PyBuffer_Release(&zb); PyBuffer_Release(&ob);
    if (!ok) return nullptr;
    Py_RETURN_NONE;
}

// Both wait, without the GIL, for a project_bin call that holds the cache.
PyObject* release_scratch(PyObject*, PyObject*) {
    Py_BEGIN_ALLOW_THREADS
    {
        std::lock_guard<std::mutex> lock(bin_scratch_mutex);
        bin_scratch = BinScratch();
    }
    Py_END_ALLOW_THREADS
    Py_RETURN_NONE;
}

PyObject* scratch_bytes(PyObject*, PyObject*) {
    size_t n = 0;
    Py_BEGIN_ALLOW_THREADS
    {
        std::lock_guard<std::mutex> lock(bin_scratch_mutex);
        n = bin_scratch.bytes();
    }
    Py_END_ALLOW_THREADS
    return PyLong_FromSize_t(n);
}

PyObject* has_avx2(PyObject*, PyObject*) { return PyBool_FromLong(cpu_has_avx2()); }
PyObject* has_avx512(PyObject*, PyObject*) { return PyBool_FromLong(cpu_has_avx512()); }

// ---- view synthesis: the float32 depth warp into the uint8 quilt (holo_viewer.render.view_synthesis,
// _warp_u8, the live path) --------------------------------------------------------------------------
// The numba kernel's expressions in its order, with its fused multiply-adds where LLVM fuses them
// (numba fastmath "contract": each a * b + c written here as one fma; the build has -ffp-contract=off so
// nothing else fuses), 16 columns at a time with AVX-512 (numba's loop is scalar): the depth row's and
// the image row's values read by permutes from a window of 32 depths / 32 texels where the 16 columns'
// reads fit in it (gathers, slow on this CPU, only where they do not). The template parameters pick
// which product of a two-product sum is fused (IA: the column iteration's interpolation, BA: the
// blend's first two taps); <true, true> is numba's (tests/test_view_synthesis.py: bit for bit).
struct WarpJob {
    const float *images, *wmaps;     // (S, H, W, 3), (S, H, W)
    const int64_t *slot, *jobs;      // (V,), (T, 3) view k, sources a, b
    const double* d;                 // (T, 4)
    const int64_t* offsets;          // (V H + 1,) or nullptr: every column
    const int32_t* columns;
    const int64_t* spans;            // (S, H, 2)
    const double* wr;                // (S, H, 2)
    uint8_t bg8[3];
    uint8_t* out;                    // (Hq, Wq, 3)
    const int64_t *row0, *col0;      // (T,)
    int64_t Wq;
    int T, H, W, iters;
};

inline void warp_live_range(const int64_t* span, const double* wr, double d0, double d1, int64_t& lo, int64_t& hi) {
    if (span[1] < span[0]) return;
    const double s0 = std::fma(d1, wr[0], d0), s1 = std::fma(d1, wr[1], d0);
    const double smin = std::min(s0, s1), smax = std::max(s0, s1);
    lo = std::min(lo, int64_t(std::floor(double(span[0]) - 2.0 - smax)));
    hi = std::max(hi, int64_t(std::ceil(double(span[1]) + 2.0 - smin)));
}

// The scalar helpers, defined twice: plain (other CPUs, mode 1) and with the AVX-512 target (the vector
// kernels' tails: std::fma inlines to one instruction there instead of a libm call)
#define HV_WARP_SCALAR(ATTR, SFX)                                                                              \
    /* numba's int(np.floor(v)) clamped to [0, W - 2], for any finite v (v clamped first: the same result) */ \
    ATTR inline int warp_floor_clamp##SFX(float v, int W) {                                                   \
        const float c = std::min(std::max(v, -1.0f), float(W));                                               \
        return std::min(std::max(int(std::floor(c)), 0), W - 2);                                              \
    }                                                                                                         \
    template <bool IA>                                                                                        \
    ATTR inline void warp_columns_scalar##SFX(const float* wrow, const int32_t* xl, int n, float d0, float d1, \
                                              int iters, int W, int32_t* i0, float* f) {                      \
        for (int i = 0; i < n; ++i) {                                                                         \
            const float xf = float(xl[i]);                                                                    \
            float xs = std::fma(d1, wrow[xl[i]], xf + d0);                                                    \
            for (int it = 0;; ++it) {                                                                         \
                const int p = warp_floor_clamp##SFX(xs, W);                                                   \
                const float fr = std::min(std::max(xs - float(p), 0.0f), 1.0f);                               \
                i0[i] = p; f[i] = fr;                                                                         \
                if (it == iters) break;                                                                       \
                const float a = (1.0f - fr), w0 = wrow[p], w1 = wrow[p + 1];                                  \
                const float inner = IA ? std::fma(a, w0, fr * w1) : std::fma(fr, w1, a * w0);                 \
                xs = std::fma(d1, inner, xf + d0);                                                            \
            }                                                                                                 \
        }                                                                                                     \
    }                                                                                                         \
    /* int() of the clamped value: the same after the clamp */                                                \
    template <bool BA>                                                                                        \
    ATTR inline uint8_t warp_blend_scalar##SFX(float ca0, float ca1, float cb0, float cb1, float A, float B,   \
                                               float C, float D) {                                            \
        float v = BA ? std::fma(ca0, A, ca1 * B) : std::fma(ca1, B, ca0 * A);                                 \
        v = std::fma(cb0, C, v);                                                                              \
        v = std::fma(cb1, D, v);                                                                              \
        const float s = std::fma(v, 255.0f, 0.5f);                                                            \
        const float c = std::min(std::max(s, -1.0f), 256.0f);                                                 \
        return uint8_t(std::min(std::max(int(c), 0), 255));                                                   \
    }                                                                                                         \
    /* channel c of texel i: its sources' columns pa, pb and fractions fa, fb, the blend weights wa, wb */     \
    template <bool BA>                                                                                        \
    ATTR inline uint8_t warp_texel_channel##SFX(const float* ia, const float* ib, const int32_t* pa,           \
                                                const int32_t* pb, const float* fa, const float* fb, float wa, \
                                                float wb, int i, int c) {                                     \
        const float ca0 = wa * (1.0f - fa[i]), ca1 = wa * fa[i], cb0 = wb * (1.0f - fb[i]), cb1 = wb * fb[i];  \
        const float* a = ia + 3 * pa[i];                                                                      \
        const float* b = ib + 3 * pb[i];                                                                      \
        return warp_blend_scalar##SFX<BA>(ca0, ca1, cb0, cb1, a[c], a[3 + c], b[c], b[3 + c]);                \
    }
HV_WARP_SCALAR(, )
#if HV_HAVE_AVX2_PATH
HV_WARP_SCALAR(HV_TARGET_AVX512, _v)
#endif

#if HV_HAVE_AVX2_PATH
// wrow[x] of 16 listed columns (increasing) of a row of W: one load where they are consecutive, a permute of
// the 32 values from column min(x[0], W - 32) where they span fewer than 32 (the interleave's listed columns
// at full tiles: every group of a live frame), else a gather
HV_TARGET_AVX512 inline __m512 warp_load16(const float* row, const int32_t* x, __m512i xv, int W) {
    if (x[15] - x[0] == 15) return _mm512_loadu_ps(row + x[0]);
    if (x[15] - x[0] < 32 && W >= 32) {
        const int b = std::min(x[0], W - 32);
        return _mm512_permutex2var_ps(_mm512_loadu_ps(row + b), _mm512_sub_epi32(xv, _mm512_set1_epi32(b)),
                                      _mm512_loadu_ps(row + b + 16));
    }
    return _mm512_i32gather_ps(xv, row, 4);
}

// (the window's first column b, whether columns p and p + 1 of every lane lie in the n columns b .. b + n - 1)
HV_TARGET_AVX512 inline bool warp_window(__m512i p, int W, int n, int& b) {
    const int pmin = _mm512_reduce_min_epi32(p), pmax = _mm512_reduce_max_epi32(p);
    b = std::min(pmin, W - n);
    return W >= n && pmax + 1 - b <= n - 1;
}

template <bool IA>
HV_TARGET_AVX512 void warp_columns16(const float* wrow, const int32_t* xl, int n, float d0, float d1, int iters,
                                     int W, int32_t* i0, float* f) {
    const __m512 vd0 = _mm512_set1_ps(d0), vd1 = _mm512_set1_ps(d1), one = _mm512_set1_ps(1.0f);
    const __m512 zero = _mm512_setzero_ps(), lo = _mm512_set1_ps(-1.0f), hi = _mm512_set1_ps(float(W));
    const __m512i izero = _mm512_setzero_si512(), imax = _mm512_set1_epi32(W - 2), ione = _mm512_set1_epi32(1);
    int i = 0;
    for (; i + 16 <= n; i += 16) {
        const __m512i x = _mm512_loadu_si512(xl + i);
        const __m512 xf = _mm512_cvtepi32_ps(x);
        const __m512 base = _mm512_add_ps(xf, vd0);
        __m512 xs = _mm512_fmadd_ps(vd1, warp_load16(wrow, xl + i, x, W), base);
        for (int it = 0;; ++it) {
            const __m512 c = _mm512_min_ps(_mm512_max_ps(xs, lo), hi);
            __m512i p = _mm512_cvttps_epi32(_mm512_roundscale_ps(c, _MM_FROUND_TO_NEG_INF | _MM_FROUND_NO_EXC));
            p = _mm512_min_epi32(_mm512_max_epi32(p, izero), imax);
            const __m512 fr = _mm512_min_ps(_mm512_max_ps(_mm512_sub_ps(xs, _mm512_cvtepi32_ps(p)), zero), one);
            _mm512_storeu_si512(i0 + i, p);
            _mm512_storeu_ps(f + i, fr);
            if (it == iters) break;
            const __m512 a = _mm512_sub_ps(one, fr);
            __m512 w0, w1;
            int b;
            if (warp_window(p, W, 32, b)) {  // row[b .. b + 31] holds every p and p + 1: two permutes
                const __m512 lo16 = _mm512_loadu_ps(wrow + b), hi16 = _mm512_loadu_ps(wrow + b + 16);
                const __m512i k = _mm512_sub_epi32(p, _mm512_set1_epi32(b));
                w0 = _mm512_permutex2var_ps(lo16, k, hi16);
                w1 = _mm512_permutex2var_ps(lo16, _mm512_add_epi32(k, ione), hi16);
            } else {
                w0 = _mm512_i32gather_ps(p, wrow, 4);
                w1 = _mm512_i32gather_ps(p, wrow + 1, 4);
            }
            const __m512 inner = IA ? _mm512_fmadd_ps(a, w0, _mm512_mul_ps(fr, w1))
                                    : _mm512_fmadd_ps(fr, w1, _mm512_mul_ps(a, w0));
            xs = _mm512_fmadd_ps(vd1, inner, base);
        }
    }
    warp_columns_scalar_v<IA>(wrow, xl + i, n - i, d0, d1, iters, W, i0 + i, f + i);
}

// The image row's texels p and p + 1 of 16 lanes (an (W, 3) float row) in six registers r0..r5 where they fit
// in a window of 32 texels (96 floats; every group of a live frame at full tiles, where 21 texels fit ~0.5 %)
// and W >= 32: returns true and t = 3 (p - window start); else false and t = 3 p (gathers). Channel c of
// texel p is then tap t + c, of p + 1 tap t + 3 + c.
struct WarpWindow {
    __m512 r0, r1, r2, r3, r4, r5;
    __m512i t;
    bool win;
};

HV_TARGET_AVX512 inline void warp_window_rgb(const float* row, __m512i p, int W, WarpWindow& w) {
    int b;
    const __m512i three = _mm512_set1_epi32(3);
    w.win = warp_window(p, W, 32, b);
    if (w.win) {
        const float* s = row + 3 * int64_t(b);
        w.r0 = _mm512_loadu_ps(s); w.r1 = _mm512_loadu_ps(s + 16); w.r2 = _mm512_loadu_ps(s + 32);
        w.r3 = _mm512_loadu_ps(s + 48); w.r4 = _mm512_loadu_ps(s + 64); w.r5 = _mm512_loadu_ps(s + 80);
        w.t = _mm512_mullo_epi32(_mm512_sub_epi32(p, _mm512_set1_epi32(b)), three);
    } else {
        w.r0 = w.r1 = w.r2 = w.r3 = w.r4 = w.r5 = _mm512_setzero_ps();
        w.t = _mm512_mullo_epi32(p, three);
    }
}

// tap t of every lane (t = w.t + offset)
HV_TARGET_AVX512 inline __m512 warp_tap(const WarpWindow& w, const float* row, __m512i t) {
    if (!w.win) return _mm512_i32gather_ps(t, row, 4);
    const __m512 lo = _mm512_permutex2var_ps(w.r0, t, w.r1);  // index bits 0-4
    const __m512 mid = _mm512_permutex2var_ps(w.r2, t, w.r3);
    const __m512 hi = _mm512_permutex2var_ps(w.r4, t, w.r5);
    const __m512 m = _mm512_mask_mov_ps(lo, _mm512_cmpge_epi32_mask(t, _mm512_set1_epi32(32)), mid);
    return _mm512_mask_mov_ps(m, _mm512_cmpge_epi32_mask(t, _mm512_set1_epi32(64)), hi);
}

// 16 texels' blend weights and both sources' windows (fa, fb, pa, pb from i), then per channel the rounded bytes
struct WarpBlend16 {
    __m512 ca0, ca1, cb0, cb1;
    WarpWindow a, b;
};

HV_TARGET_AVX512 inline void warp_blend16_setup(const float* ia, const float* ib, const int32_t* pa, const int32_t* pb,
                                                const float* fa, const float* fb, float wa, float wb, int W,
                                                WarpBlend16& s) {
    const __m512 vwa = _mm512_set1_ps(wa), vwb = _mm512_set1_ps(wb), one = _mm512_set1_ps(1.0f);
    const __m512 fa_ = _mm512_loadu_ps(fa), fb_ = _mm512_loadu_ps(fb);
    s.ca0 = _mm512_mul_ps(vwa, _mm512_sub_ps(one, fa_)); s.ca1 = _mm512_mul_ps(vwa, fa_);
    s.cb0 = _mm512_mul_ps(vwb, _mm512_sub_ps(one, fb_)); s.cb1 = _mm512_mul_ps(vwb, fb_);
    // the texels p and p + 1 of every lane from a 32-texel window in registers, else gathers
    warp_window_rgb(ia, _mm512_loadu_si512(pa), W, s.a);
    warp_window_rgb(ib, _mm512_loadu_si512(pb), W, s.b);
}

// channel ch (per lane) of the 16 texels, rounded half up and clamped as warp_u8 does: 0..255 per 32-bit lane
template <bool BA>
HV_TARGET_AVX512 inline __m512i warp_blend16_channel(const WarpBlend16& s, const float* ia, const float* ib,
                                                     __m512i ch) {
    const __m512i three = _mm512_set1_epi32(3);
    const __m512i tac = _mm512_add_epi32(s.a.t, ch), tbc = _mm512_add_epi32(s.b.t, ch);
    const __m512i tac3 = _mm512_add_epi32(tac, three), tbc3 = _mm512_add_epi32(tbc, three);
    const __m512 A = warp_tap(s.a, ia, tac), B = warp_tap(s.a, ia, tac3);
    const __m512 C = warp_tap(s.b, ib, tbc), D = warp_tap(s.b, ib, tbc3);
    __m512 v = BA ? _mm512_fmadd_ps(s.ca0, A, _mm512_mul_ps(s.ca1, B)) : _mm512_fmadd_ps(s.ca1, B, _mm512_mul_ps(s.ca0, A));
    v = _mm512_fmadd_ps(s.cb0, C, v);
    v = _mm512_fmadd_ps(s.cb1, D, v);
    const __m512 r = _mm512_fmadd_ps(v, _mm512_set1_ps(255.0f), _mm512_set1_ps(0.5f));
    const __m512 c = _mm512_min_ps(_mm512_max_ps(r, _mm512_set1_ps(-1.0f)), _mm512_set1_ps(256.0f));
    return _mm512_min_epi32(_mm512_max_epi32(_mm512_cvttps_epi32(c), _mm512_setzero_si512()), _mm512_set1_epi32(255));
}

template <bool BA>
HV_TARGET_AVX512 void warp_blend16(const float* ia, const float* ib, const int32_t* pa, const int32_t* pb,
                                   const float* fa, const float* fb, float wa, float wb, int n, int W, uint8_t* rgb) {
    const __m512i pack3 = _mm512_broadcast_i32x4(_mm_setr_epi8(0, 1, 2, 4, 5, 6, 8, 9, 10, 12, 13, 14, -1, -1, -1, -1));
    int i = 0;
    for (; i + 16 <= n; i += 16) {
        WarpBlend16 s;
        warp_blend16_setup(ia, ib, pa + i, pb + i, fa + i, fb + i, wa, wb, W, s);
        __m512i res[3];
        for (int c = 0; c < 3; ++c) res[c] = warp_blend16_channel<BA>(s, ia, ib, _mm512_set1_epi32(c));
        // the 16 pixels' bytes (0..255 each) interleaved r, g, b: one 32-bit word per pixel, its three
        // low bytes packed per 128-bit lane (12 of 16 bytes), four 16-byte stores 12 bytes apart (each
        // writing 4 bytes the next overwrites; rgb has room past 3 n). Was 48 byte stores: 7 % of the warp.
        const __m512i px = _mm512_or_si512(res[0], _mm512_or_si512(_mm512_slli_epi32(res[1], 8),
                                                                    _mm512_slli_epi32(res[2], 16)));
        const __m512i packed = _mm512_shuffle_epi8(px, pack3);
        uint8_t* o = rgb + 3 * i;
        _mm_storeu_si128(reinterpret_cast<__m128i*>(o), _mm512_castsi512_si128(packed));
        _mm_storeu_si128(reinterpret_cast<__m128i*>(o + 12), _mm512_extracti32x4_epi32(packed, 1));
        _mm_storeu_si128(reinterpret_cast<__m128i*>(o + 24), _mm512_extracti32x4_epi32(packed, 2));
        _mm_storeu_si128(reinterpret_cast<__m128i*>(o + 36), _mm512_extracti32x4_epi32(packed, 3));
    }
    for (; i < n; ++i)
        for (int c = 0; c < 3; ++c) rgb[3 * i + c] = warp_texel_channel_v<BA>(ia, ib, pa, pb, fa, fb, wa, wb, i, c);
}
#endif

// n pixels of the background colour bg (3 bytes) from o: 16-pixel copies of a 48-byte pattern, then bytes
inline void warp_fill_bg(uint8_t* o, int64_t n, const uint8_t* bg) {
    uint8_t pat[48];
    for (int p = 0; p < 16; ++p) { pat[3 * p] = bg[0]; pat[3 * p + 1] = bg[1]; pat[3 * p + 2] = bg[2]; }
    int64_t p = 0;
    for (; p + 16 <= n; p += 16) std::memcpy(o + 3 * p, pat, 48);
    std::memcpy(o + 3 * p, pat, size_t(3 * (n - p)));
}

// One warp job's constants (view k from sources a < k < b: their slots, blend weights, column offsets)
struct WarpRow {
    int64_t k, sa, sb;
    float wa, wb, da0, da1, db0, db1;
    const double* dj;
};

inline WarpRow warp_row_job(const WarpJob& J, int j) {
    WarpRow R;
    const int64_t k = J.jobs[3 * j], a = J.jobs[3 * j + 1], b = J.jobs[3 * j + 2];
    R.k = k; R.sa = J.slot[a]; R.sb = J.slot[b];
    R.wa = float(double(b - k) / double(b - a));
    R.wb = 1.0f - R.wa;
    R.dj = J.d + 4 * j;
    R.da0 = float(R.dj[0]); R.da1 = float(R.dj[1]); R.db0 = float(R.dj[2]); R.db1 = float(R.dj[3]);
    return R;
}

// [n0, n1): the listed columns xall[0 .. nx) of row y that can read a non-background pixel of either source
inline void warp_row_live(const WarpJob& J, const WarpRow& R, int y, const int32_t* xall, int64_t nx, int64_t& n0,
                          int64_t& n1) {
    const int H = J.H;
    int64_t lo = J.W, hi = -1;
    warp_live_range(J.spans + (R.sa * H + y) * 2, J.wr + (R.sa * H + y) * 2, R.dj[0], R.dj[1], lo, hi);
    warp_live_range(J.spans + (R.sb * H + y) * 2, J.wr + (R.sb * H + y) * 2, R.dj[2], R.dj[3], lo, hi);
    n0 = n1 = nx;
    if (hi >= lo) {  // the columns before lo and after hi: a scan over them (they are filled next) instead
        n0 = 0;      // of binary searches, whose dependent reads of a row not yet in cache took ~2 ms a frame
        while (n0 < nx && xall[n0] < lo) ++n0;
        while (n1 > n0 && xall[n1 - 1] > hi) --n1;
    }
}

// both sources' columns (i0, f) of the n listed columns xl of row y; ia, ib: the sources' image rows
template <bool IA>
inline void warp_row_columns(const WarpJob& J, const WarpRow& R, int y, const int32_t* xl, int n, bool wide,
                             int32_t* i0a, float* fa, int32_t* i0b, float* fb, const float*& ia, const float*& ib) {
    const int H = J.H, W = J.W;
    const float* wra = J.wmaps + (R.sa * H + y) * W;
    const float* wrb = J.wmaps + (R.sb * H + y) * W;
    ia = J.images + (R.sa * H + y) * int64_t(W) * 3;
    ib = J.images + (R.sb * H + y) * int64_t(W) * 3;
#if HV_HAVE_AVX2_PATH
    if (wide) {
        warp_columns16<IA>(wra, xl, n, R.da0, R.da1, J.iters, W, i0a, fa);
        warp_columns16<IA>(wrb, xl, n, R.db0, R.db1, J.iters, W, i0b, fb);
        return;
    }
#endif
    warp_columns_scalar<IA>(wra, xl, n, R.da0, R.da1, J.iters, W, i0a, fa);
    warp_columns_scalar<IA>(wrb, xl, n, R.db0, R.db1, J.iters, W, i0b, fb);
}

template <bool IA, bool BA>
void warp_rows(const WarpJob& J, int j, int y0, int y1, bool wide, std::vector<int32_t>& every,
               std::vector<int32_t>& buf_i, std::vector<float>& buf_f, std::vector<uint8_t>& rgb) {
    const int H = J.H, W = J.W;
    const WarpRow R = warp_row_job(J, j);
    const int64_t k = R.k;
    const float wa = R.wa, wb = R.wb;
    int32_t *i0a = buf_i.data(), *i0b = buf_i.data() + W;
    float *fa = buf_f.data(), *fb = buf_f.data() + W;
    for (int y = y0; y < y1; ++y) {
        const int32_t* xall;
        int64_t nx;
        if (J.offsets) {
            const int64_t o0 = J.offsets[k * H + y], o1 = J.offsets[k * H + y + 1];
            xall = J.columns + o0; nx = o1 - o0;
        } else {
            xall = every.data(); nx = W;
        }
        int64_t n0, n1;
        warp_row_live(J, R, y, xall, nx, n0, n1);
        uint8_t* orow = J.out + (J.row0[j] + y) * J.Wq * 3;
        const int64_t c0 = J.col0[j];
        if (nx > 0 && xall[nx - 1] - xall[0] == nx - 1) {  // consecutive columns: two runs of background
            warp_fill_bg(orow + (c0 + xall[0]) * 3, n0, J.bg8);
            warp_fill_bg(orow + (c0 + xall[n1 < nx ? n1 : 0]) * 3, nx - n1, J.bg8);
        } else {
            for (int64_t i = 0; i < nx; ++i) {  // columns outside [n0, n1): background
                if (i == n0) i = n1;
                if (i >= nx) break;
                uint8_t* o = orow + (c0 + xall[i]) * 3;
                o[0] = J.bg8[0]; o[1] = J.bg8[1]; o[2] = J.bg8[2];
            }
        }
        const int32_t* xl = xall + n0;
        const int n = int(n1 - n0);
        if (n <= 0) continue;
        const float *ia, *ib;
        warp_row_columns<IA>(J, R, y, xl, n, wide, i0a, fa, i0b, fb, ia, ib);
#if HV_HAVE_AVX2_PATH
        if (wide) {
            warp_blend16<BA>(ia, ib, i0a, i0b, fa, fb, wa, wb, n, W, rgb.data());
        } else
#endif
        {
            for (int i = 0; i < n; ++i)
                for (int c = 0; c < 3; ++c)
                    rgb[3 * i + c] = warp_texel_channel<BA>(ia, ib, i0a, i0b, fa, fb, wa, wb, i, c);
        }
        if (xl[n - 1] - xl[0] == n - 1) {  // consecutive columns (sorted, distinct): one copy
            std::memcpy(orow + (c0 + xl[0]) * 3, rgb.data(), size_t(3 * n));
        } else {
            for (int i = 0; i < n; ++i) {
                uint8_t* o = orow + (c0 + xl[i]) * 3;
                o[0] = rgb[3 * i]; o[1] = rgb[3 * i + 1]; o[2] = rgb[3 * i + 2];
            }
        }
    }
}

using WarpRowsFn = void (*)(const WarpJob&, int, int, int, bool, std::vector<int32_t>&, std::vector<int32_t>&,
                            std::vector<float>&, std::vector<uint8_t>&);

// The listed-column table (offsets (V H + 1,), columns) lies inside its buffers: offsets increasing within
// [0, n_cols], each row's first and last column in [0, W) (warp_views checks the rest of the table's range)
inline bool warp_table_ok(const WarpJob& J, int64_t V, int64_t n_cols) {
    const int64_t H = J.H;
    for (int64_t i = 0; i <= V * H; ++i)
        if (J.offsets[i] < 0 || J.offsets[i] > n_cols || (i > 0 && J.offsets[i] < J.offsets[i - 1])) return false;
    for (int64_t r = 0; r < V * H; ++r)
        if (J.offsets[r + 1] != J.offsets[r] && (J.columns[J.offsets[r]] < 0 || J.columns[J.offsets[r + 1] - 1] >= J.W))
            return false;
    return true;
}

// the AVX-512 row functions (mode 0 on a CPU that has it), else the scalar ones
inline bool warp_wide(int mode) {
#if HV_HAVE_AVX2_PATH
    return mode == 0 && cpu_has_avx512();
#else
    (void)mode;
    return false;
#endif
}

PyObject* warp_u8(PyObject*, PyObject* args) {
    Py_buffer images{}, wmaps{}, slot{}, jobs{}, d{}, offsets{}, columns{}, spans{}, wr{}, bg{}, out{}, row0{}, col0{};
    WarpJob J{};
    int S, V, Hq, Wq, n_threads, mode;
    if (!PyArg_ParseTuple(args, "y*y*y*y*y*iy*y*y*y*y*w*y*y*iiiiiiiii", &images, &wmaps, &slot, &jobs, &d, &J.iters,
                          &offsets, &columns, &spans, &wr, &bg, &out, &row0, &col0, &S, &V, &J.T, &J.H, &J.W, &Hq, &Wq,
                          &n_threads, &mode))
        return nullptr;
    bool ok = S > 0 && V > 0 && J.T >= 0 && J.H > 0 && J.W >= 2 && Hq > 0 && Wq > 0 && J.iters >= 0;
    if (!ok) PyErr_SetString(PyExc_ValueError, "_splat_cpp.warp_u8: inconsistent sizes");
    const int64_t H = J.H, W = J.W;
    ok = ok && need(images, S * H * W * 12, "images") && need(wmaps, S * H * W * 4, "wmaps") && need(slot, V * 8LL, "slot") &&
         need(jobs, J.T * 24LL, "jobs") && need(d, J.T * 32LL, "d") && need(spans, S * H * 16, "spans") &&
         need(wr, S * H * 16, "wr") && need(bg, 12, "bg") && need(out, int64_t(Hq) * Wq * 3, "out") &&
         need(row0, J.T * 8LL, "row0") && need(col0, J.T * 8LL, "col0");
    const bool listed = offsets.len > 0;
    ok = ok && (!listed || need(offsets, (V * H + 1) * 8, "offsets"));
    if (ok) {
        J.images = (const float*)images.buf; J.wmaps = (const float*)wmaps.buf; J.slot = (const int64_t*)slot.buf;
        J.jobs = (const int64_t*)jobs.buf; J.d = (const double*)d.buf; J.spans = (const int64_t*)spans.buf;
        J.wr = (const double*)wr.buf; J.out = (uint8_t*)out.buf; J.row0 = (const int64_t*)row0.buf;
        J.col0 = (const int64_t*)col0.buf; J.Wq = Wq;
        J.offsets = listed ? (const int64_t*)offsets.buf : nullptr;
        J.columns = (const int32_t*)columns.buf;
        const int64_t n_cols = columns.len / 4;
        for (int c = 0; c < 3; ++c) {  // numba: min(max(int(bg[c] * 255.0 + 0.5), 0), 255), fused
            const double v = std::min(std::max(std::fma(double(((const float*)bg.buf)[c]), 255.0, 0.5), -1.0), 256.0);
            J.bg8[c] = uint8_t(std::min(std::max(int(v), 0), 255));
        }
        // every index the kernel follows lies inside its buffers (checked, not trusted)
        for (int j = 0; ok && j < J.T; ++j) {
            const int64_t k = J.jobs[3 * j], a = J.jobs[3 * j + 1], b = J.jobs[3 * j + 2];
            ok = k >= 0 && k < V && a >= 0 && a < V && b >= 0 && b < V && a < b && J.slot[a] >= 0 && J.slot[a] < S &&
                 J.slot[b] >= 0 && J.slot[b] < S && J.row0[j] >= 0 && J.row0[j] + H <= Hq && J.col0[j] >= 0 &&
                 J.col0[j] + W <= Wq;
        }
        ok = ok && (!listed || warp_table_ok(J, V, n_cols));
        if (!ok) PyErr_SetString(PyExc_ValueError, "_splat_cpp.warp_u8: a job, tile or column lies outside the arrays");
    }
    if (ok) {
        // numba's fusions (both sums fused on their first product): the same bytes, tested; the other
        // three choices differ on ~1e-5 of the pixels by 1 (measured on live frames)
        const WarpRowsFn fn = warp_rows<true, true>;
        const bool wide = warp_wide(mode);
        const int rows = 16;
        const int per = (J.H + rows - 1) / rows;
        Py_BEGIN_ALLOW_THREADS
        parallel_for(J.T * per, std::max(1, n_threads), [&](int item) {
            thread_local std::vector<int32_t> every, bi;
            thread_local std::vector<float> bf;
            thread_local std::vector<uint8_t> rgb;
            if (int(every.size()) < J.W) {
                every.resize(size_t(J.W));
                for (int x = 0; x < J.W; ++x) every[size_t(x)] = x;
            }
            if (bi.size() < size_t(2 * J.W)) bi.resize(size_t(2 * J.W));
            if (bf.size() < size_t(2 * J.W)) bf.resize(size_t(2 * J.W));
            if (rgb.size() < size_t(3 * J.W + 16)) rgb.resize(size_t(3 * J.W + 16));  // warp_blend16 writes 4 past
            const int j = item % J.T, y0 = (item / J.T) * rows;
            fn(J, j, y0, std::min(J.H, y0 + rows), wide, every, bi, bf, rgb);
        });
        Py_END_ALLOW_THREADS
    }
    PyBuffer_Release(&images); PyBuffer_Release(&wmaps); PyBuffer_Release(&slot); PyBuffer_Release(&jobs);
    PyBuffer_Release(&d); PyBuffer_Release(&offsets); PyBuffer_Release(&columns); PyBuffer_Release(&spans);
    PyBuffer_Release(&wr); PyBuffer_Release(&bg); PyBuffer_Release(&out); PyBuffer_Release(&row0); PyBuffer_Release(&col0);
    if (!ok) return nullptr;
    Py_RETURN_NONE;
}


// ---- view synthesis straight into the native image (warp_native) ----------------------------------------
// The interleave (nearest mode) shows each native subpixel one channel of one quilt texel; with view synthesis
// the warp wrote the quilt's read texels (3 channels each) and the interleave then gathered one byte per
// subpixel. warp_native writes the subpixels themselves: per listed texel (k, y, x) a code of its one or two
// destination subpixels (view_synthesis.native_targets: byte b = (p << 2) | channel, the subpixel at
// rowoff[y] + coloff[x] + lut[b]; a texel read once repeats its byte), the channel of each computed with
// warp_u8's expressions in its order (so the same byte the quilt held and the interleave copied), the source
// views' subpixels with to_uint8's arithmetic from their renders (their tiles' bytes). Work items are bands of
// texel rows with every view: a band's native rows are written by one thread.
struct NativeJob {
    WarpJob w;                       // out, row0, col0, Wq unused
    const int64_t* job_of;           // (V,) the warp job of view k, or -1 (a source)
    const uint32_t* xc;              // parallel to columns: column | code << 16 (one stream, 4 bytes a texel)
    const int64_t* rowoff;           // (H,) native offset of each texel row's first subpixel row
    const int32_t* coloff;           // (W,)
    const int32_t* lut;              // (256,)
    uint8_t* native;
    int V;
};

// Asks for the listed columns and codes of view k's texel row y ahead of their use: a row's entries are read
// once a frame (27 MB in all), and its first reads (the background scans from both ends) waited on them
inline void native_prefetch_row(const NativeJob& N, int64_t k, int y) {
    const WarpJob& J = N.w;
    const int64_t o0 = J.offsets[k * J.H + y], o1 = J.offsets[k * J.H + y + 1];
    const char* a = reinterpret_cast<const char*>(N.xc + o0);
    for (int64_t o = 0; o < (o1 - o0) * 4; o += 64) __builtin_prefetch(a + o);
}

// how many rows ahead (1 / 2 / 3: 28.5 / 28.1 / 26.9 ms a full-tile call, two process pairs, load 2.3-2.7)
constexpr int NATIVE_PREFETCH_ROWS = 3;


#if HV_HAVE_AVX2_PATH
// 16 texels' two destination bytes: the blend of the channel each names (codes' low and high byte)
template <bool BA>
HV_TARGET_AVX512 void warp_blend16_native(const float* ia, const float* ib, const int32_t* pa, const int32_t* pb,
                                          const float* fa, const float* fb, float wa, float wb, const uint16_t* codes,
                                          int n, int W, uint8_t* v0, uint8_t* v1) {
    const __m512i ch_mask = _mm512_set1_epi32(3);
    int i = 0;
    for (; i + 16 <= n; i += 16) {
        WarpBlend16 s;
        warp_blend16_setup(ia, ib, pa + i, pb + i, fa + i, fb + i, wa, wb, W, s);
        const __m512i code = _mm512_cvtepu16_epi32(_mm256_loadu_si256(reinterpret_cast<const __m256i*>(codes + i)));
        const __m512i r0 = warp_blend16_channel<BA>(s, ia, ib, _mm512_and_si512(code, ch_mask));
        const __m512i r1 = warp_blend16_channel<BA>(s, ia, ib, _mm512_and_si512(_mm512_srli_epi32(code, 8), ch_mask));
        _mm_storeu_si128(reinterpret_cast<__m128i*>(v0 + i), _mm512_cvtepi32_epi8(r0));
        _mm_storeu_si128(reinterpret_cast<__m128i*>(v1 + i), _mm512_cvtepi32_epi8(r1));
    }
    for (; i < n; ++i) {
        v0[i] = warp_texel_channel_v<BA>(ia, ib, pa, pb, fa, fb, wa, wb, i, codes[i] & 3);
        v1[i] = warp_texel_channel_v<BA>(ia, ib, pa, pb, fa, fb, wa, wb, i, (codes[i] >> 8) & 3);
    }
}
#endif

template <bool IA, bool BA>
void warp_native_rows(const NativeJob& N, int j, int y0, int y1, bool wide, std::vector<int32_t>& buf_i,
                      std::vector<float>& buf_f, std::vector<uint8_t>& vals, std::vector<int32_t>& xbuf,
                      std::vector<uint16_t>& cbuf) {
    const WarpJob& J = N.w;
    const int H = J.H, W = J.W;
    const WarpRow R = warp_row_job(J, j);
    const int64_t k = R.k;
    const float wa = R.wa, wb = R.wb;
    int32_t *i0a = buf_i.data(), *i0b = buf_i.data() + W;
    float *fa = buf_f.data(), *fb = buf_f.data() + W;
    uint8_t *v0 = vals.data(), *v1 = vals.data() + W + 16;
    const int32_t* __restrict lut = N.lut;
    for (int y = y0; y < y1; ++y) {
        const int64_t o0 = J.offsets[k * H + y], o1 = J.offsets[k * H + y + 1];
        const int64_t nx = o1 - o0;
        if (y + NATIVE_PREFETCH_ROWS < y1) native_prefetch_row(N, k, y + NATIVE_PREFETCH_ROWS);
        if (nx == 0) continue;
        int32_t* __restrict xs = xbuf.data();
        uint16_t* __restrict cs = cbuf.data();
        const uint32_t* __restrict xc = N.xc + o0;
        for (int64_t i = 0; i < nx; ++i) { xs[i] = int32_t(xc[i] & 0xFFFF); cs[i] = uint16_t(xc[i] >> 16); }
        const int32_t* __restrict xall = xs;
        const uint16_t* __restrict call = cs;
        int64_t n0, n1;
        warp_row_live(J, R, y, xall, nx, n0, n1);
        // (byte stores may alias anything: the loops read their tables through local restrict pointers)
        uint8_t* __restrict nrow = N.native + N.rowoff[y];
        const int32_t* __restrict coloff = N.coloff;
        const uint8_t bg[4] = {J.bg8[0], J.bg8[1], J.bg8[2], 0};
        for (int64_t i = 0; i < n0; ++i) {  // columns outside [n0, n1): background
            const int32_t base = coloff[xall[i]];
            const int c0 = call[i] & 0xFF, c1 = call[i] >> 8;
            nrow[base + lut[c0]] = bg[c0 & 3];
            nrow[base + lut[c1]] = bg[c1 & 3];
        }
        for (int64_t i = n1; i < nx; ++i) {
            const int32_t base = coloff[xall[i]];
            const int c0 = call[i] & 0xFF, c1 = call[i] >> 8;
            nrow[base + lut[c0]] = bg[c0 & 3];
            nrow[base + lut[c1]] = bg[c1 & 3];
        }
        const int32_t* __restrict xl = xall + n0;
        const uint16_t* __restrict cl = call + n0;
        const int n = int(n1 - n0);
        if (n <= 0) continue;
        const float *ia, *ib;
        warp_row_columns<IA>(J, R, y, xl, n, wide, i0a, fa, i0b, fb, ia, ib);
#if HV_HAVE_AVX2_PATH
        if (wide) {
            warp_blend16_native<BA>(ia, ib, i0a, i0b, fa, fb, wa, wb, cl, n, W, v0, v1);
        } else
#endif
        {
            for (int i = 0; i < n; ++i) {
                v0[i] = warp_texel_channel<BA>(ia, ib, i0a, i0b, fa, fb, wa, wb, i, cl[i] & 3);
                v1[i] = warp_texel_channel<BA>(ia, ib, i0a, i0b, fa, fb, wa, wb, i, (cl[i] >> 8) & 3);
            }
        }
        const uint8_t* __restrict r0 = v0;
        const uint8_t* __restrict r1 = v1;
        for (int i = 0; i < n; ++i) {  // a texel read once names its byte twice: the same value, twice
            const int32_t base = coloff[xl[i]];
            const int c = cl[i];
            nrow[base + lut[c & 0xFF]] = r0[i];
            nrow[base + lut[c >> 8]] = r1[i];
        }
    }
}

// holo_viewer.images.to_uint8 of one float32 value: rint(v * 255) (half to even), NaN -> 0, clipped to [0, 255]
inline uint8_t native_to_uint8(float v) {
    float s = std::nearbyint(v * 255.0f);
    s = s > 0.0f ? s : 0.0f;
    s = s < 255.0f ? s : 255.0f;
    return uint8_t(s);
}

// the subpixels of source view k's rows y0 .. y1 - 1: to_uint8 of its render (the bytes of its quilt tile; the
// rows are in cache, read by the warps of the views beside it)
inline void native_source_rows(const NativeJob& N, int64_t k, int y0, int y1) {
    const WarpJob& J = N.w;
    const int H = J.H, W = J.W;
    const int32_t* __restrict lut = N.lut;
    const int32_t* __restrict coloff = N.coloff;
    const uint32_t* __restrict xcs = N.xc;
    for (int y = y0; y < y1; ++y) {
        const int64_t o0 = J.offsets[k * H + y], o1 = J.offsets[k * H + y + 1];
        if (y + NATIVE_PREFETCH_ROWS < y1) native_prefetch_row(N, k, y + NATIVE_PREFETCH_ROWS);
        const float* __restrict irow = J.images + (J.slot[k] * H + y) * int64_t(W) * 3;
        uint8_t* __restrict nrow = N.native + N.rowoff[y];
        for (int64_t i = o0; i < o1; ++i) {
            const int x = int(xcs[i] & 0xFFFF), c = int(xcs[i] >> 16);
            const int c0 = c & 0xFF, c1 = c >> 8;
            const uint8_t a = native_to_uint8(irow[3 * x + (c0 & 3)]), b = native_to_uint8(irow[3 * x + (c1 & 3)]);
            const int32_t base = coloff[x];
            nrow[base + lut[c0]] = a;
            nrow[base + lut[c1]] = b;
        }
    }
}

PyObject* warp_native(PyObject*, PyObject* args) {
    Py_buffer images{}, wmaps{}, slot{}, jobs{}, d{}, offsets{}, columns{}, xc{}, spans{}, wr{}, bg{}, job_of{},
        rowoff{}, coloff{}, lut{}, native{};
    NativeJob N{};
    WarpJob& J = N.w;
    int S, n_threads, mode;
    if (!PyArg_ParseTuple(args, "y*y*y*y*y*iy*y*y*y*y*y*y*y*y*y*w*iiiiiii", &images, &wmaps, &slot, &jobs, &d,
                          &J.iters, &offsets, &columns, &xc, &spans, &wr, &bg, &job_of, &rowoff, &coloff, &lut,
                          &native, &S, &N.V, &J.T, &J.H, &J.W, &n_threads, &mode))
        return nullptr;
    const int V = N.V;
    bool ok = S > 0 && V > 0 && J.T >= 0 && J.H > 0 && J.W >= 2 && J.iters >= 0;
    if (!ok) PyErr_SetString(PyExc_ValueError, "_splat_cpp.warp_native: inconsistent sizes");
    const int64_t H = J.H, W = J.W;
    ok = ok && need(images, S * H * W * 12, "images") && need(wmaps, S * H * W * 4, "wmaps") &&
         need(slot, V * 8LL, "slot") && need(jobs, J.T * 24LL, "jobs") && need(d, J.T * 32LL, "d") &&
         need(spans, S * H * 16, "spans") && need(wr, S * H * 16, "wr") && need(bg, 12, "bg") &&
         need(job_of, V * 8LL, "job_of") && need(offsets, (V * H + 1) * 8, "offsets") &&
         need(rowoff, H * 8, "rowoff") && need(coloff, W * 4, "coloff") && need(lut, 256 * 4, "lut");
    const int64_t n_cols = columns.len / 4, n_nat = native.len;
    ok = ok && need(xc, n_cols * 4, "xc");
    if (ok) {
        J.images = (const float*)images.buf; J.wmaps = (const float*)wmaps.buf; J.slot = (const int64_t*)slot.buf;
        J.jobs = (const int64_t*)jobs.buf; J.d = (const double*)d.buf; J.spans = (const int64_t*)spans.buf;
        J.wr = (const double*)wr.buf; J.offsets = (const int64_t*)offsets.buf; J.columns = (const int32_t*)columns.buf;
        N.job_of = (const int64_t*)job_of.buf;
        N.xc = (const uint32_t*)xc.buf; N.rowoff = (const int64_t*)rowoff.buf;
        N.coloff = (const int32_t*)coloff.buf; N.lut = (const int32_t*)lut.buf; N.native = (uint8_t*)native.buf;
        for (int c = 0; c < 3; ++c) {  // warp_u8's background bytes
            const double v = std::min(std::max(std::fma(double(((const float*)bg.buf)[c]), 255.0, 0.5), -1.0), 256.0);
            J.bg8[c] = uint8_t(std::min(std::max(int(v), 0), 255));
        }
        // every index the kernel follows lies inside its buffers (checked, not trusted)
        for (int64_t kk = 0; ok && kk < V; ++kk) {
            const int64_t j = N.job_of[kk], s = J.slot[kk];
            ok = (j >= 0) != (s >= 0) && j < J.T && s < S && (j < 0 || J.jobs[3 * j] == kk);
        }
        for (int j = 0; ok && j < J.T; ++j) {
            const int64_t k = J.jobs[3 * j], a = J.jobs[3 * j + 1], b = J.jobs[3 * j + 2];
            ok = k >= 0 && k < V && a >= 0 && a < V && b >= 0 && b < V && a < b && J.slot[a] >= 0 && J.slot[a] < S &&
                 J.slot[b] >= 0 && J.slot[b] < S && N.job_of[k] == j;
        }
        ok = ok && warp_table_ok(J, V, n_cols);
        for (int64_t r = 0; ok && r < V * H; ++r)  // xc's columns: a row's first and last within [0, W) too
            ok = J.offsets[r + 1] == J.offsets[r] ||
                 (int64_t(N.xc[J.offsets[r]] & 0xFFFF) < W && int64_t(N.xc[J.offsets[r + 1] - 1] & 0xFFFF) < W);
        // rowoff[y] + coloff[x] + lut[b] inside the native image for every y, x and b
        int64_t rmin = INT64_MAX, rmax = INT64_MIN, cmin = INT64_MAX, cmax = INT64_MIN, lmin = INT64_MAX, lmax = INT64_MIN;
        for (int64_t y = 0; y < H; ++y) { rmin = std::min(rmin, N.rowoff[y]); rmax = std::max(rmax, N.rowoff[y]); }
        for (int64_t x = 0; x < W; ++x) { cmin = std::min(cmin, int64_t(N.coloff[x])); cmax = std::max(cmax, int64_t(N.coloff[x])); }
        for (int b = 0; b < 256; ++b) { lmin = std::min(lmin, int64_t(N.lut[b])); lmax = std::max(lmax, int64_t(N.lut[b])); }
        ok = ok && rmin + cmin + lmin >= 0 && rmax + cmax + lmax < n_nat;
        if (!ok) PyErr_SetString(PyExc_ValueError, "_splat_cpp.warp_native: a job, tile, column or target lies outside the arrays");
    }
    if (ok) {
        const auto fn = warp_native_rows<true, true>;
        const bool wide = warp_wide(mode);
        const int rows = 8;  // texel rows a work item (2, 4, 8, 16: the same CPU within 1 ms, measured)
        const int per = (J.H + rows - 1) / rows;
        Py_BEGIN_ALLOW_THREADS
        parallel_for(per, std::max(1, n_threads), [&](int item) {
            thread_local std::vector<int32_t> bi, xbuf;
            thread_local std::vector<float> bf;
            thread_local std::vector<uint8_t> vals;
            thread_local std::vector<uint16_t> cbuf;
            if (xbuf.size() < size_t(J.W)) xbuf.resize(size_t(J.W));
            if (cbuf.size() < size_t(J.W)) cbuf.resize(size_t(J.W));
            if (bi.size() < size_t(2 * J.W)) bi.resize(size_t(2 * J.W));
            if (bf.size() < size_t(2 * J.W)) bf.resize(size_t(2 * J.W));
            if (vals.size() < size_t(2 * J.W + 32)) vals.resize(size_t(2 * J.W + 32));
            const int y0 = item * rows, y1 = std::min(J.H, y0 + rows);
            for (int k = 0; k < N.V; ++k) {
                for (int d = 0; k + 1 < N.V && d < NATIVE_PREFETCH_ROWS && y0 + d < y1; ++d)
                    native_prefetch_row(N, k + 1, y0 + d);
                if (N.job_of[k] < 0) native_source_rows(N, k, y0, y1);
                else fn(N, int(N.job_of[k]), y0, y1, wide, bi, bf, vals, xbuf, cbuf);
            }
        });
        Py_END_ALLOW_THREADS
    }
    for (Py_buffer* b : {&images, &wmaps, &slot, &jobs, &d, &offsets, &columns, &xc, &spans, &wr, &bg, &job_of,
                         &rowoff, &coloff, &lut, &native})
        PyBuffer_Release(b);
    if (!ok) return nullptr;
    Py_RETURN_NONE;
}

// ---- view_synthesis._row_extents: per (source, row) the non-background span and the depth range ----------
// spans (S, H, 2) int64: the first and last column whose colour differs from bg in any channel ((W, -1) for
// none); wr (S, H, 2) float64: the row's smallest and largest inverse depth. The numba kernel's values
// exactly (float compares and min / max); AVX-512: 16 pixels' 48 floats compared with the background's
// period-3 pattern at a time, from each end, and the depths' min / max 16 at a time.
#if HV_HAVE_AVX2_PATH
// bit j: float j of the 48 from s differs from the background pattern p0 | p1 | p2
HV_TARGET_AVX512 inline uint64_t row_differs48(const float* s, __m512 p0, __m512 p1, __m512 p2) {
    const uint64_t a = _mm512_cmp_ps_mask(_mm512_loadu_ps(s), p0, _CMP_NEQ_UQ);
    const uint64_t b = _mm512_cmp_ps_mask(_mm512_loadu_ps(s + 16), p1, _CMP_NEQ_UQ);
    const uint64_t c = _mm512_cmp_ps_mask(_mm512_loadu_ps(s + 32), p2, _CMP_NEQ_UQ);
    return a | (b << 16) | (c << 32);
}

inline bool px_differs(const float* img, int x, const float* bg) {
    const float* s = img + 3 * int64_t(x);
    return s[0] != bg[0] || s[1] != bg[1] || s[2] != bg[2];
}

HV_TARGET_AVX512 void row_extent_avx512(const float* img, const float* w, const float* bg, int W, int64_t* span,
                                        double* range) {
    float pat[48];
    for (int i = 0; i < 48; ++i) pat[i] = bg[i % 3];
    const __m512 p0 = _mm512_loadu_ps(pat), p1 = _mm512_loadu_ps(pat + 16), p2 = _mm512_loadu_ps(pat + 32);
    int lo = W, hi = -1;
    int x = 0;
    for (; x + 16 <= W; x += 16) {
        const uint64_t m = row_differs48(img + 3 * int64_t(x), p0, p1, p2);
        if (m) { lo = x + __builtin_ctzll(m) / 3; break; }
    }
    if (lo == W)
        for (; x < W; ++x)
            if (px_differs(img, x, bg)) { lo = x; break; }
    if (lo < W) {  // the last one: from the right end
        int e = W;
        for (; e - 16 >= lo; e -= 16) {
            const uint64_t m = row_differs48(img + 3 * int64_t(e - 16), p0, p1, p2);
            if (m) { hi = e - 16 + (63 - __builtin_clzll(m)) / 3; break; }
        }
        if (hi < 0)
            for (int xx = e - 1; xx >= lo; --xx)
                if (px_differs(img, xx, bg)) { hi = xx; break; }
    }
    span[0] = lo; span[1] = hi;
    __m512 vmin = _mm512_set1_ps(INFINITY), vmax = _mm512_set1_ps(-INFINITY);
    int i = 0;
    for (; i + 16 <= W; i += 16) {
        const __m512 v = _mm512_loadu_ps(w + i);
        vmin = _mm512_min_ps(vmin, v); vmax = _mm512_max_ps(vmax, v);
    }
    float mn = _mm512_reduce_min_ps(vmin), mx = _mm512_reduce_max_ps(vmax);
    for (; i < W; ++i) { mn = std::min(mn, w[i]); mx = std::max(mx, w[i]); }
    range[0] = W > 0 ? double(mn) : INFINITY; range[1] = W > 0 ? double(mx) : -INFINITY;
}
#endif

void row_extent_scalar(const float* img, const float* w, const float* bg, int W, int64_t* span, double* range) {
    int lo = W, hi = -1;
    for (int x = 0; x < W; ++x) {
        const float* s = img + 3 * int64_t(x);
        if (s[0] != bg[0] || s[1] != bg[1] || s[2] != bg[2]) {
            if (lo == W) lo = x;
            hi = x;
        }
    }
    span[0] = lo; span[1] = hi;
    double mn = INFINITY, mx = -INFINITY;
    for (int x = 0; x < W; ++x) { mn = std::min(mn, double(w[x])); mx = std::max(mx, double(w[x])); }
    range[0] = mn; range[1] = mx;
}

PyObject* row_extents(PyObject*, PyObject* args) {
    Py_buffer images{}, wmaps{}, bg{}, spans{}, wr{};
    int S, H, W, n_threads, mode;
    if (!PyArg_ParseTuple(args, "y*y*y*w*w*iiiii", &images, &wmaps, &bg, &spans, &wr, &S, &H, &W, &n_threads, &mode))
        return nullptr;
    bool ok = S >= 0 && H >= 0 && W >= 0;
    if (!ok) PyErr_SetString(PyExc_ValueError, "_splat_cpp.row_extents: inconsistent sizes");
    const int64_t rows = int64_t(S) * H;
    ok = ok && need(images, rows * W * 12, "images") && need(wmaps, rows * W * 4, "wmaps") && need(bg, 12, "bg") &&
         need(spans, rows * 16, "spans") && need(wr, rows * 16, "wr");
    if (ok) {
        const float* img = (const float*)images.buf;
        const float* w = (const float*)wmaps.buf;
        const float* b = (const float*)bg.buf;
        int64_t* sp = (int64_t*)spans.buf;
        double* r = (double*)wr.buf;
#if HV_HAVE_AVX2_PATH
        const bool wide = mode == 0 && cpu_has_avx512();
#else
        const bool wide = false;
#endif
        const int chunk = 64;
        Py_BEGIN_ALLOW_THREADS
        parallel_for(int((rows + chunk - 1) / chunk), std::max(1, n_threads), [&](int c) {
            for (int64_t i = int64_t(c) * chunk; i < std::min(rows, int64_t(c + 1) * chunk); ++i) {
#if HV_HAVE_AVX2_PATH
                if (wide) { row_extent_avx512(img + i * W * 3, w + i * W, b, W, sp + 2 * i, r + 2 * i); continue; }
#endif
                row_extent_scalar(img + i * W * 3, w + i * W, b, W, sp + 2 * i, r + 2 * i);
            }
        });
        Py_END_ALLOW_THREADS
    }
    PyBuffer_Release(&images); PyBuffer_Release(&wmaps); PyBuffer_Release(&bg); PyBuffer_Release(&spans);
    PyBuffer_Release(&wr);
    if (!ok) return nullptr;
    Py_RETURN_NONE;
}

PyMethodDef methods[] = {
    {"composite", composite, METH_VARARGS,
     "composite(rec, off, base, ids, nv, m, tile, tiles_x, tiles_y, width, height, alpha_threshold, "
     "alpha_cap, t_min, bg, clip, out, blends, n_threads, mode, jobs) -> 'avx512' | 'avx2' | 'scalar'\n\n"
     "Blend per-(view, tile) splat lists front to back into out (V, H, W, 3) float32. mode: 0 auto, "
     "1 scalar, 2 require AVX2, 3 require AVX-512 (16x16 tiles). jobs: int32 view * tiles + tile of the "
     "tiles to composite (the others are left as they are in out), or empty for all."},
    {"project_bin", project_bin, METH_VARARGS,
     "project_bin(pc, cov, means, opacity, q, sh, cams, m, mp, nv, width, height, degree, use_shared, tile, "
     "tiles_x, tiles_y, near, dilation, radius_sigmas, alpha_threshold, cull_margin, rec, off, base, seen, ids, "
     "n_threads[, vmask, vmask_views]) -> (total entries, seconds spent filling the lists)\n\n"
     "vmask (vmask_views, mp) uint8, optional: per view v < vmask_views, the depth-ordered splats it draws "
     "(0: its box written empty, nothing binned).\n"
     "cams (nv, 29) float64: fast_kernels.project_views' 14 parameters, then the pixel rectangle x0, x1, "
     "y0, y1 every box is clipped to (the image, or a region of it: splats that cannot reach it are "
     "skipped by a conservative test before projection), then a crossed-slit view's flag and its 10 "
     "parameters (0 for a pinhole; see project_views).\n"
     "fast_kernels.project_views, count_tiles and fill_tiles in one pass over the splats (inputs in depth "
     "order, float64 structure of arrays with row stride mp, a multiple of 8 >= m, padding opacity 0; "
     "sh float32). Writes rec, off, base, seen and, when ids holds them, the tile lists; returns the "
     "number of entries (larger than ids' capacity: nothing written to ids, grow it and call again)."},
    {"prep_sorted", prep_sorted, METH_VARARGS,
     "prep_sorted(order, means, quats, log_scales, opacity, colours, Wrot, pc, cov, mout, op, sh, m, mp, n, c, "
     "float32, n_threads) -> None\n\nholo_viewer.render.fast_kernels.prep_sorted (bit-identical): the splats in depth "
     "order as structures of arrays (row stride mp), camera-frame centres and covariances computed."},
    {"argsort_stable", argsort_stable, METH_VARARGS,
     "argsort_stable(z, order) -> None\n\nnumpy.argsort(z, kind='stable') of float64 z into int64 order (LSD "
     "radix sort; identical, ties in index order)."},
    {"release_scratch", release_scratch, METH_NOARGS,
     "Free the tile counts and (splat, tile) entries project_bin keeps between calls."},
    {"scratch_bytes", scratch_bytes, METH_NOARGS, "Bytes project_bin's kept scratch holds."},
    {"has_avx2", has_avx2, METH_NOARGS, "True when the CPU runs the AVX2+FMA path."},
    {"warp_u8", warp_u8, METH_VARARGS,
     "warp_u8(images, wmaps, slot, jobs, d, iters, offsets, columns, spans, wr, bg, out, row0, col0, S, V, T, H, W, "
     "Hq, Wq, n_threads, mode) -> None\n\n"
     "holo_viewer.render.view_synthesis._warp_u8 (the float32 warp into the uint8 quilt) with its fused "
     "multiply-adds, the same bytes; mode 1: scalar only."},
    {"warp_native", warp_native, METH_VARARGS,
     "warp_native(images, wmaps, slot, jobs, d, iters, offsets, columns, codes, spans, wr, bg, job_of, rowoff, "
     "coloff, lut, native, S, V, T, H, W, n_threads, mode) -> None\n\n"
     "warp_u8 + the nearest interleave in one pass: every native subpixel of the listed texels (codes: "
     "view_synthesis.native_targets) written, the synthesized views' with warp_u8's bytes, the sources' with "
     "to_uint8's of their renders (their quilt tiles' bytes); mode 1: scalar only."},
    {"row_extents", row_extents, METH_VARARGS,
     "row_extents(images, wmaps, bg, spans, wr, S, H, W, n_threads, mode) -> None\n\n"
     "holo_viewer.render.view_synthesis._row_extents (the same values): per (source, row) the first and last "
     "column not of the background colour ((W, -1) for none) and the inverse depth's min and max; mode 1: scalar."},
    {"has_avx512", has_avx512, METH_NOARGS, "True when the CPU runs the AVX-512 path (16x16 tiles)."},
    {nullptr, nullptr, 0, nullptr}};

PyModuleDef moddef = {PyModuleDef_HEAD_INIT, "_splat_cpp",
                      "C++ tile compositor of holo_viewer's fast splat renderer.", -1, methods};

}  // namespace

PyMODINIT_FUNC PyInit__splat_cpp(void) { return PyModule_Create(&moddef); }
