// Eye slices -> the native subpixels a tracked viewer's eyes receive (holo_viewer/display/slices.py), and the
// nearest-mode interleave's row gather (holo_viewer/display/lenticular.py, gather_rows below):
// the same float32 expressions, in the same order, as its numba kernel (the build has
// -ffp-contract=off, and every clamp is a select with the AVX-512 max/min semantics, NaN -> the
// bound), so the two agree bit for bit (tested). Nearest mode runs 16 subpixels at a time with
// AVX-512 where the CPU has it (the feather's blend per written lane after); blend mode and other
// CPUs run the scalar loop.
#include "hv_common.h"

#include <cmath>
#include <cstdint>
#include <cstring>

namespace {

using hv::cpu_has_avx512;
using hv::need;
using hv::parallel_for;

struct SliceJob {
    uint8_t* native;                       // (H, W3)
    const int16_t* pos;                    // (H W3,) per row sorted by (view, position)
    const float* zeta;                     // (H W3,) lens coordinate of each listed subpixel
    const int32_t* off;                    // (H, V + 1)
    const int32_t *tex_row, *tex_col;      // (H,), (W,)
    const int16_t* view1;                  // blend: (H W3,) upper view (native order)
    const uint16_t* w8;                    // blend: (H W3,) weight of the upper view, 1/256
    const int64_t* segs;                   // (S, 4) eye, view, x0, x1
    const float* bounds;                   // (E, 2, W) t_lo, t_hi
    const float *images, *wmaps, *kv, *gh; // (E, hv, wv, 3), (E, hv, wv), (E, V, 2), (E, 2)
    int64_t* counts;                       // (H,)
    const uint8_t* contested;              // (S,) 1: another eye's reach may overlap the segment's
    float reach;
    float inner;                           // feathered when inner < reach: the slice's weight ramps to 0 there
    int blend, n_segs, iters, H, W3, V, E, hv, wv;
};

inline void slice_column(float xi, int wv, int& p, float& f) {
    float xm = xi - 0.5f;
    xm = xm > -1.0f ? xm : -1.0f;
    xm = xm < float(wv) ? xm : float(wv);
    p = int(std::floor(xm));
    p = p > 0 ? p : 0;
    p = p < wv - 2 ? p : wv - 2;
    f = xm - float(p);
    f = f > 0.0f ? f : 0.0f;
    f = f < 1.0f ? f : 1.0f;
}

inline float slice_value(const float* img, const float* wrow, int ch, float uc, float d0, float d1, float g,
                         float h, int iters, int wv) {
    float w = wrow[int(uc)];
    float xi = (uc + d0 + d1 * w) / (g + h * w);
    int p;
    float f;
    for (int it = 0; it < iters; ++it) {
        slice_column(xi, wv, p, f);
        const float w0 = wrow[p];
        w = w0 + f * (wrow[p + 1] - w0);
        xi = (uc + d0 + d1 * w) / (g + h * w);
    }
    slice_column(xi, wv, p, f);
    const float a = img[p * 3 + ch];
    float v = std::nearbyint((a + f * (img[p * 3 + 3 + ch] - a)) * 255.0f);
    v = v > 0.0f ? v : 0.0f;
    return v < 255.0f ? v : 255.0f;
}

inline float slice_gap(float zeta, float lo, float hi, float n) {
    float best = INFINITY;
    for (int s = 0; s < 3; ++s) {
        const float z = zeta + float(s - 1) * n;
        const float a = lo - z, b = z - hi;
        const float gap = a > b ? a : b;
        best = gap < best ? gap : best;
    }
    return best;
}

// searchsorted (left) of value in the sorted int16 run [lo, hi)
inline int lower_bound16(const int16_t* row, int lo, int hi, int value) {
    while (lo < hi) {
        const int mid = (lo + hi) >> 1;
        if (row[mid] < value) lo = mid + 1; else hi = mid;
    }
    return lo;
}

// the same, for a run of positions spread about evenly over [0, span) (a view's subpixels along a
// native row): a short walk from the interpolated index instead of a binary search
inline int lower_bound_spread(const int16_t* row, int lo, int hi, int value, int span) {
    if (lo >= hi) return lo;
    int i = lo + int(int64_t(hi - lo) * value / span);
    i = i < lo ? lo : (i > hi ? hi : i);
    for (int s = 0; s < 4; ++s) {  // the answer is i when row[i - 1] < value <= row[i]
        if (i > lo && row[i - 1] >= value) --i;
        else if (i < hi && row[i] < value) ++i;
        else return i;
    }
    if (i > lo && row[i - 1] >= value) return lower_bound16(row, lo, i, value);
    return lower_bound16(row, i, hi, value);
}

// the value (0..255, integral) eye e's slice gives subpixel p of row y showing view k (blend: and view1)
inline float eye_value(const SliceJob& J, int y, int e, int k, int p) {
    const int64_t base = int64_t(y) * J.W3;
    const int ty = J.tex_row[y];
    const int x = p / 3;
    const float* img = J.images + (int64_t(e) * J.hv + ty) * J.wv * 3;
    const float* wrow = J.wmaps + (int64_t(e) * J.hv + ty) * J.wv;
    const float* kve = J.kv + int64_t(e) * J.V * 2;
    const float g = J.gh[2 * e], h = J.gh[2 * e + 1];
    const int ch = p - 3 * x;
    const float uc = float(J.tex_col[x]) + 0.5f;
    const float v0 = slice_value(img, wrow, ch, uc, kve[2 * k], kve[2 * k + 1], g, h, J.iters, J.wv);
    if (!J.blend) return v0;
    const int64_t sidx = base + p;
    const int k1 = J.view1[sidx];
    const float v1 = k1 == k ? v0 : slice_value(img, wrow, ch, uc, kve[2 * k1], kve[2 * k1 + 1], g, h, J.iters, J.wv);
    const uint32_t ww = J.w8[sidx];
    return float((uint32_t(v0) * (256 - ww) + uint32_t(v1) * ww + 128) >> 8);
}

// the feather's weight of a slice whose eye's range is gap views away: 1 up to inner, 0 from reach
inline float feather_weight(float gap, float reach, float inv) {
    float w = (reach - gap) * inv;
    w = w > 0.0f ? w : 0.0f;
    return w < 1.0f ? w : 1.0f;
}

// the feathered write of one subpixel (scalar loop and the AVX-512 path's lanes alike): the eye's value
// ``ve`` at weight ``we``, blended with the nearest other eye ``ob`` (gap ``gob``) where it also reaches,
// then laid over the fill already in the native image by the larger weight, rounded and clamped
inline void feather_write(const SliceJob& J, int y, int k, int p, int64_t base, float ve, float we,
                          int ob, float gob, float inv) {
    float s = ve;
    if (ob >= 0 && gob < J.reach) {
        const float wo = feather_weight(gob, J.reach, inv);
        const float vo = eye_value(J, y, ob, k, p);
        s = (we * ve + wo * vo) / (we + wo);
        we = we > wo ? we : wo;
    }
    const float f = float(J.native[base + p]);
    float v = std::nearbyint(f + we * (s - f));
    v = v > 0.0f ? v : 0.0f;
    v = v < 255.0f ? v : 255.0f;
    J.native[base + p] = uint8_t(v);
}

// subpixels [a, b) of row y's bucket of view k, from eye e's slice; returns how many were written
int64_t slice_run_scalar(const SliceJob& J, int y, int e, int k, int a, int b) {
    const int64_t base = int64_t(y) * J.W3;
    const int W = J.W3 / 3;
    const float* tlo = J.bounds + int64_t(e) * 2 * W;
    const float* thi = tlo + W;
    const float n = float(J.V);
    const bool feather = J.inner < J.reach;
    const float inv = feather ? 1.0f / (J.reach - J.inner) : 0.0f;
    int64_t cnt = 0;
    for (int i = a; i < b; ++i) {
        const int p = J.pos[base + i];
        const int x = p / 3;
        const float z = J.zeta[base + i];
        const float gap = slice_gap(z, tlo[x], thi[x], n);
        if (!(gap < J.reach)) continue;
        bool mine = true;  // a subpixel both eyes receive: the nearer eye's
        int ob = -1;       // the nearest other eye and its gap
        float gob = INFINITY;
        for (int o = 0; o < J.E; ++o) {
            if (o == e) continue;
            const float* olo = J.bounds + int64_t(o) * 2 * W;
            const float go = slice_gap(z, olo[x], olo[W + x], n);
            if (go < gap || (go == gap && o < e)) mine = false;
            if (go < gob) { gob = go; ob = o; }
        }
        if (!mine) continue;
        const float ve = eye_value(J, y, e, k, p);
        if (!feather) {
            J.native[base + p] = uint8_t(ve);
        } else {
            // the eyes' slices blended by their weights, over the fill by the larger weight
            feather_write(J, y, k, p, base, ve, feather_weight(gap, J.reach, inv), ob, gob, inv);
        }
        ++cnt;
    }
    return cnt;
}

// Per segment, 1 when a subpixel of it that its eye can receive (lens coordinate within reach of
// that eye's range) may also be within reach of another eye's range at the same column, i.e.
// when the nearer-eye test can reject it; 0 when, at every column of the segment, the eyes'
// ranges widened by the reach lie apart (by 1e-3 views, in float64: far beyond the float32
// rounding of the test) for every shift by the period. Where 0 the test is skipped: the same
// result (a candidate's own gap is < reach, another eye's is >= reach).
std::vector<uint8_t> segments_contested(const SliceJob& J) {
    const int W = J.W3 / 3;
    const double n = J.V, r = J.reach, eps = 1e-3;
    std::vector<uint8_t> col(size_t(J.E) * W, 0);
    for (int e = 0; e < J.E; ++e)
        for (int o = 0; o < J.E; ++o) {
            if (o == e) continue;
            const float *le = J.bounds + int64_t(e) * 2 * W, *lo = J.bounds + int64_t(o) * 2 * W;
            for (int x = 0; x < W; ++x) {
                const double a0 = double(le[x]) - r, a1 = double(le[W + x]) + r;
                bool apart = a0 == a0 && a1 == a1;  // NaN: contested
                for (int s = -2; s <= 2 && apart; ++s) {
                    const double b0 = double(lo[x]) - r + s * n, b1 = double(lo[W + x]) + r + s * n;
                    apart = (b0 > a1 + eps) || (b1 < a0 - eps);
                }
                if (!apart) col[size_t(e) * W + x] = 1;
            }
        }
    std::vector<uint8_t> seg(size_t(J.n_segs) + 1, 0);
    for (int j = 0; j < J.n_segs; ++j) {
        const int64_t* sg = J.segs + 4 * j;
        for (int64_t x = sg[2]; x < sg[3] && !seg[size_t(j)]; ++x) seg[size_t(j)] = col[size_t(sg[0]) * W + x];
    }
    return seg;
}

#if HV_HAVE_AVX2_PATH
HV_TARGET_AVX512 inline void slice_column16(__m512 xi, __m512 wvf, __m512i wv2, __m512i& p, __m512& f) {
    __m512 xm = _mm512_sub_ps(xi, _mm512_set1_ps(0.5f));
    xm = _mm512_max_ps(xm, _mm512_set1_ps(-1.0f));  // (xm > -1) ? xm : -1, NaN -> -1
    xm = _mm512_min_ps(xm, wvf);
    p = _mm512_cvttps_epi32(_mm512_floor_ps(xm));
    p = _mm512_min_epi32(_mm512_max_epi32(p, _mm512_setzero_si512()), wv2);
    f = _mm512_sub_ps(xm, _mm512_cvtepi32_ps(p));
    f = _mm512_min_ps(_mm512_max_ps(f, _mm512_setzero_ps()), _mm512_set1_ps(1.0f));
}

HV_TARGET_AVX512 inline __m512 slice_gap16(__m512 z0, __m512 lo, __m512 hi, __m512 n) {
    __m512 best = _mm512_set1_ps(INFINITY);
    for (int s = 0; s < 3; ++s) {
        const __m512 z = _mm512_add_ps(z0, _mm512_mul_ps(_mm512_set1_ps(float(s - 1)), n));
        const __m512 gap = _mm512_max_ps(_mm512_sub_ps(lo, z), _mm512_sub_ps(z, hi));
        best = _mm512_min_ps(gap, best);
    }
    return best;
}

// One native row in nearest mode, 16 subpixels at a time: the row's candidates of every segment
// are first copied into one list (position, lens coordinate, eye, warp coefficients), so the long
// dependency chain of a warp (gather, divide, floor, gather, ...) overlaps across many vectors
// instead of stalling on each segment's one or two (2-3x faster than vectors per segment, measured).
struct SliceRowBuf {
    std::vector<int32_t> p, seg_e;  // per candidate: position | segment << 16; per segment: eye | contested << 8
    std::vector<float> z, seg_d0, seg_d1;  // per candidate: lens coordinate; per segment: warp coefficients
    // up to 64 segments: the tables live in registers and are read by permutes, not gathers
    bool small = false, tex_affine = false;
    float tex_scale = 0.0f;
    __m512 tab[3][4];
    HV_TARGET_AVX512 explicit SliceRowBuf(const SliceJob& J)
        : seg_e(size_t(std::max(J.n_segs, 64)) + 1), seg_d0(size_t(std::max(J.n_segs, 64)) + 1),
          seg_d1(size_t(std::max(J.n_segs, 64)) + 1) {
        for (int j = 0; j < J.n_segs; ++j) {
            const int e = int(J.segs[4 * j]), k = int(J.segs[4 * j + 1]);
            seg_e[size_t(j)] = e | (J.contested[j] << 8);
            seg_d0[size_t(j)] = J.kv[(int64_t(e) * J.V + k) * 2];
            seg_d1[size_t(j)] = J.kv[(int64_t(e) * J.V + k) * 2 + 1];
        }
        small = J.n_segs <= 64;
        for (int r = 0; r < 4; ++r) {
            tab[0][r] = _mm512_castsi512_ps(_mm512_loadu_si512(seg_e.data() + 16 * r));
            tab[1][r] = _mm512_loadu_ps(seg_d0.data() + 16 * r);
            tab[2][r] = _mm512_loadu_ps(seg_d1.data() + 16 * r);
        }
        // the texel column of native column x as floor((x + 1/2) wv / W) in float32, the kernel's
        // expression, where that reproduces the table for every column (the Portrait's does)
        const int W = J.W3 / 3;
        tex_scale = float(J.wv) / float(W);
        tex_affine = true;
        for (int x = 0; x < W && tex_affine; ++x)
            tex_affine = int(std::floor((float(x) + 0.5f) * tex_scale)) == J.tex_col[x];
    }
    HV_TARGET_AVX512 __m512 lookup(__m512i j, const std::vector<float>& t, int which) const {
        if (!small) return _mm512_i32gather_ps(j, t.data(), 4);
        const __m512 lo = _mm512_permutex2var_ps(tab[which + 1][0], j, tab[which + 1][1]);
        const __m512 hi = _mm512_permutex2var_ps(tab[which + 1][2], j, tab[which + 1][3]);
        return _mm512_mask_mov_ps(lo, _mm512_test_epi32_mask(j, _mm512_set1_epi32(32)), hi);
    }
    HV_TARGET_AVX512 __m512i lookup_e(__m512i j) const {
        if (!small) return _mm512_i32gather_epi32(j, seg_e.data(), 4);
        const __m512 lo = _mm512_permutex2var_ps(tab[0][0], j, tab[0][1]);
        const __m512 hi = _mm512_permutex2var_ps(tab[0][2], j, tab[0][3]);
        return _mm512_castps_si512(_mm512_mask_mov_ps(lo, _mm512_test_epi32_mask(j, _mm512_set1_epi32(32)), hi));
    }
    void reserve(size_t n) {
        if (p.size() < n + 16) { p.resize(n + 16); z.resize(n + 16); }
    }
};

HV_TARGET_AVX512 int64_t slice_row_avx512(const SliceJob& J, int y, SliceRowBuf& R) {
    const int64_t base = int64_t(y) * J.W3;
    const int32_t* o = J.off + int64_t(y) * (J.V + 1);
    const int W = J.W3 / 3;
    R.reserve(size_t(J.W3) * 2);
    int n = 0;
    for (int j = 0; j < J.n_segs; ++j) {  // gather the row's candidates
        const int64_t* sg = J.segs + 4 * j;
        const int e = int(sg[0]), k = int(sg[1]);
        const int a = lower_bound_spread(J.pos + base, o[k], o[k + 1], int(3 * sg[2]), J.W3);
        const int b = lower_bound_spread(J.pos + base, a, o[k + 1], int(3 * sg[3]), J.W3);
        if (size_t(n + (b - a) + 16) > R.p.size()) R.reserve(size_t(n + (b - a)) * 2);
        for (int i = a; i < b; ++i, ++n) {
            R.p[n] = int32_t(J.pos[base + i]) | (j << 16);  // position and segment (< 32768 of each)
            R.z[n] = J.zeta[base + i];
        }
    }
    const int ty = J.tex_row[y];
    const int64_t plane = int64_t(J.hv) * J.wv;
    const __m512i wrow0 = _mm512_set1_epi32(int32_t(int64_t(ty) * J.wv));  // row ty's first pixel in a slice
    const __m512i eplane = _mm512_set1_epi32(int32_t(plane));
    const __m512 wvf = _mm512_set1_ps(float(J.wv)), reach = _mm512_set1_ps(J.reach), nv = _mm512_set1_ps(float(J.V));
    const __m512i wv2 = _mm512_set1_epi32(J.wv - 2), two_w = _mm512_set1_epi32(2 * W), one = _mm512_set1_epi32(1);
    const __m512i three = _mm512_set1_epi32(3);
    const __m512 tex_scale = _mm512_set1_ps(R.tex_scale);
    alignas(64) int32_t pv[16], vv[16], jv[16];
    alignas(64) float bv[16];
    const bool feather = J.inner < J.reach;
    const float inv = feather ? 1.0f / (J.reach - J.inner) : 0.0f;
    int64_t cnt = 0;
    for (int i = 0; i < n; i += 16) {
        const int len = std::min(16, n - i);
        __mmask16 m = len == 16 ? __mmask16(0xFFFF) : __mmask16((1u << len) - 1);
        const __m512i pj = _mm512_maskz_loadu_epi32(m, R.p.data() + i);
        const __m512i p = _mm512_and_si512(pj, _mm512_set1_epi32(0xFFFF)), sj = _mm512_srli_epi32(pj, 16);
        const __m512i ef = R.lookup_e(sj);  // the segment's eye (| 256: contested)
        const __m512i e = _mm512_and_si512(ef, _mm512_set1_epi32(0xFF));
        const __mmask16 contested = _mm512_test_epi32_mask(ef, _mm512_set1_epi32(0x100));
        const __m512 z0 = _mm512_maskz_loadu_ps(m, R.z.data() + i);
        const __m512i x = _mm512_srli_epi32(_mm512_mullo_epi32(p, _mm512_set1_epi32(43691)), 17);  // p / 3
        const __m512i ch = _mm512_sub_epi32(p, _mm512_mullo_epi32(x, three));
        const __m512i bx = _mm512_add_epi32(_mm512_mullo_epi32(e, two_w), x);  // bounds[e, 0, x]
        const __m512 best = slice_gap16(z0, _mm512_mask_i32gather_ps(_mm512_setzero_ps(), m, bx, J.bounds, 4),
                                        _mm512_mask_i32gather_ps(_mm512_setzero_ps(), m,
                                                                 _mm512_add_epi32(bx, _mm512_set1_epi32(W)), J.bounds, 4),
                                        nv);
        m &= _mm512_cmp_ps_mask(best, reach, _CMP_LT_OQ);
        for (int oe = 0; (m & contested) && oe < J.E; ++oe) {  // a subpixel both eyes receive: the nearer eye's
            const __mmask16 other = m & contested & _mm512_cmpneq_epi32_mask(e, _mm512_set1_epi32(oe));
            if (!other) continue;
            const __m512i ox = _mm512_add_epi32(_mm512_set1_epi32(oe * 2 * W), x);
            const __m512 go = slice_gap16(z0, _mm512_mask_i32gather_ps(_mm512_setzero_ps(), other, ox, J.bounds, 4),
                                          _mm512_mask_i32gather_ps(_mm512_setzero_ps(), other,
                                                                   _mm512_add_epi32(ox, _mm512_set1_epi32(W)), J.bounds, 4),
                                          nv);
            const __mmask16 lower = _mm512_cmpgt_epi32_mask(e, _mm512_set1_epi32(oe));  // oe < e
            m &= ~(other & (_mm512_cmp_ps_mask(go, best, _CMP_LT_OQ) | (lower & _mm512_cmp_ps_mask(go, best, _CMP_EQ_OQ))));
        }
        if (!m) continue;
        const __m512 d0 = R.lookup(sj, R.seg_d0, 0), d1 = R.lookup(sj, R.seg_d1, 1);
        __m512 g = _mm512_set1_ps(J.gh[0]), h = _mm512_set1_ps(J.gh[1]);  // the eyes' (few): selects, not gathers
        for (int oe = 1; oe < J.E; ++oe) {
            const __mmask16 is = _mm512_cmpeq_epi32_mask(e, _mm512_set1_epi32(oe));
            g = _mm512_mask_mov_ps(g, is, _mm512_set1_ps(J.gh[2 * oe]));
            h = _mm512_mask_mov_ps(h, is, _mm512_set1_ps(J.gh[2 * oe + 1]));
        }
        const __m512i rowbase = _mm512_add_epi32(_mm512_mullo_epi32(e, eplane), wrow0);  // slice e, row ty
        const __m512i u = R.tex_affine ? _mm512_cvttps_epi32(_mm512_floor_ps(_mm512_mul_ps(
                                             _mm512_add_ps(_mm512_cvtepi32_ps(x), _mm512_set1_ps(0.5f)), tex_scale)))
                                       : _mm512_mask_i32gather_epi32(_mm512_setzero_si512(), m, x, J.tex_col, 4);
        const __m512 uc = _mm512_add_ps(_mm512_cvtepi32_ps(u), _mm512_set1_ps(0.5f));
        __m512 w = _mm512_mask_i32gather_ps(_mm512_setzero_ps(), m, _mm512_add_epi32(rowbase, u), J.wmaps, 4);
        __m512 xi = _mm512_div_ps(_mm512_add_ps(_mm512_add_ps(uc, d0), _mm512_mul_ps(d1, w)),
                                  _mm512_add_ps(g, _mm512_mul_ps(h, w)));
        __m512i q;
        __m512 f;
        for (int it = 0; it < J.iters; ++it) {
            slice_column16(xi, wvf, wv2, q, f);
            const __m512i at = _mm512_add_epi32(rowbase, q);
            const __m512 w0 = _mm512_mask_i32gather_ps(_mm512_setzero_ps(), m, at, J.wmaps, 4);
            const __m512 w1 = _mm512_mask_i32gather_ps(_mm512_setzero_ps(), m, _mm512_add_epi32(at, one), J.wmaps, 4);
            w = _mm512_add_ps(w0, _mm512_mul_ps(f, _mm512_sub_ps(w1, w0)));
            xi = _mm512_div_ps(_mm512_add_ps(_mm512_add_ps(uc, d0), _mm512_mul_ps(d1, w)),
                               _mm512_add_ps(g, _mm512_mul_ps(h, w)));
        }
        slice_column16(xi, wvf, wv2, q, f);
        const __m512i at = _mm512_add_epi32(_mm512_mullo_epi32(_mm512_add_epi32(rowbase, q), three), ch);
        const __m512 va = _mm512_mask_i32gather_ps(_mm512_setzero_ps(), m, at, J.images, 4);
        const __m512 vb = _mm512_mask_i32gather_ps(_mm512_setzero_ps(), m, _mm512_add_epi32(at, three), J.images, 4);
        __m512 v = _mm512_roundscale_ps(_mm512_mul_ps(_mm512_add_ps(va, _mm512_mul_ps(f, _mm512_sub_ps(vb, va))),
                                                      _mm512_set1_ps(255.0f)),
                                        _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC);
        v = _mm512_min_ps(_mm512_max_ps(v, _mm512_setzero_ps()), _mm512_set1_ps(255.0f));
        _mm512_store_si512(vv, _mm512_cvttps_epi32(v));
        _mm512_store_si512(pv, p);
        if (!feather) {
            for (unsigned bits = m; bits; bits &= bits - 1) {
                const int l = __builtin_ctz(bits);
                J.native[base + pv[l]] = uint8_t(vv[l]);
                ++cnt;
            }
            continue;
        }
        // feathered: the scalar loop's blend per written lane (its own value computed above; another
        // eye's gap < reach only where the segment is contested, so only there the other eyes are tried)
        _mm512_store_ps(bv, best);
        _mm512_store_si512(jv, sj);
        const unsigned cmask = unsigned(contested);
        for (unsigned bits = m; bits; bits &= bits - 1) {
            const int l = __builtin_ctz(bits);
            const int64_t* sg = J.segs + 4 * jv[l];
            const int el = int(sg[0]), kl = int(sg[1]), pl = pv[l], xl = pl / 3;
            int ob = -1;
            float gob = INFINITY;
            if (cmask & (1u << l)) {
                for (int oe = 0; oe < J.E; ++oe) {
                    if (oe == el) continue;
                    const float* olo = J.bounds + int64_t(oe) * 2 * W;
                    const float go = slice_gap(R.z[size_t(i + l)], olo[xl], olo[W + xl], float(J.V));
                    if (go < gob) { gob = go; ob = oe; }
                }
            }
            feather_write(J, y, kl, pl, base, float(vv[l]), feather_weight(bv[l], J.reach, inv), ob, gob, inv);
            ++cnt;
        }
    }
    return cnt;
}
#endif

PyObject* scatter_slices(PyObject*, PyObject* args) {
    Py_buffer native{}, pos{}, zeta{}, off{}, tex_row{}, tex_col{}, view1{}, w8{}, segs{}, bounds{}, images{},
        wmaps{}, kv{}, gh{}, counts{};
    SliceJob J{};
    int blend, n_threads, mode = 0;
    J.inner = INFINITY;
    if (!PyArg_ParseTuple(args, "w*y*y*y*y*y*y*y*py*y*fy*y*y*y*iw*iiiiiii|if", &native, &pos, &zeta, &off, &tex_row,
                          &tex_col, &view1, &w8, &blend, &segs, &bounds, &J.reach, &images, &wmaps, &kv, &gh,
                          &J.iters, &counts, &J.H, &J.W3, &J.V, &J.E, &J.hv, &J.wv, &n_threads, &mode, &J.inner))
        return nullptr;
    J.blend = blend;
    const int64_t nsub = int64_t(J.H) * J.W3;
    J.n_segs = int(segs.len / (4 * 8));
    bool ok = J.H > 0 && J.W3 > 0 && J.W3 % 3 == 0 && J.V > 0 && J.E > 0 && J.hv > 0 && J.wv >= 2 && J.iters >= 0 &&
              J.W3 < 32768 && segs.len % 32 == 0;
    if (!ok) PyErr_SetString(PyExc_ValueError, "_splat_cpp.scatter_slices: inconsistent sizes");
    ok = ok && need(native, nsub, "native") && need(pos, nsub * 2, "positions") && need(zeta, nsub * 4, "zeta") &&
         need(off, int64_t(J.H) * (J.V + 1) * 4, "offsets") && need(tex_row, int64_t(J.H) * 4, "tex_row") &&
         need(tex_col, int64_t(J.W3 / 3) * 4, "tex_col") && (!blend || (need(view1, nsub * 2, "view1") &&
         need(w8, nsub * 2, "w8"))) && need(bounds, int64_t(J.E) * 2 * (J.W3 / 3) * 4, "bounds") &&
         need(images, int64_t(J.E) * J.hv * J.wv * 12, "images") && need(wmaps, int64_t(J.E) * J.hv * J.wv * 4, "wmaps") &&
         need(kv, int64_t(J.E) * J.V * 8, "kv") && need(gh, int64_t(J.E) * 8, "gh") && need(counts, int64_t(J.H) * 8, "counts");
    if (ok) {
        J.native = (uint8_t*)native.buf; J.pos = (const int16_t*)pos.buf; J.zeta = (const float*)zeta.buf;
        J.off = (const int32_t*)off.buf; J.tex_row = (const int32_t*)tex_row.buf; J.tex_col = (const int32_t*)tex_col.buf;
        J.view1 = (const int16_t*)view1.buf; J.w8 = (const uint16_t*)w8.buf; J.segs = (const int64_t*)segs.buf;
        J.bounds = (const float*)bounds.buf; J.images = (const float*)images.buf; J.wmaps = (const float*)wmaps.buf;
        J.kv = (const float*)kv.buf; J.gh = (const float*)gh.buf; J.counts = (int64_t*)counts.buf;
        for (int j = 0; ok && j < J.n_segs; ++j) {  // the tables' texels must lie inside the slices
            const int64_t* sg = J.segs + 4 * j;
            ok = sg[0] >= 0 && sg[0] < J.E && sg[1] >= 0 && sg[1] < J.V && sg[2] >= 0 && sg[3] <= J.W3 / 3;
        }
        if (!ok) PyErr_SetString(PyExc_ValueError, "_splat_cpp.scatter_slices: a segment is outside the tables");
    }
    std::vector<uint8_t> contested;
    if (ok) {
        contested = segments_contested(J);
        J.contested = contested.data();
    }
    if (ok) {
        const bool wide = !blend && mode != 1 && cpu_has_avx512() && J.n_segs < 32768;
        const int chunk = 16;  // rows per work item
        Py_BEGIN_ALLOW_THREADS
        parallel_for((J.H + chunk - 1) / chunk, std::max(1, n_threads), [&](int c) {
#if HV_HAVE_AVX2_PATH
            if (wide) {
                SliceRowBuf R(J);
                for (int y = c * chunk; y < std::min(J.H, c * chunk + chunk); ++y) J.counts[y] = slice_row_avx512(J, y, R);
                return;
            }
#endif
            for (int y = c * chunk; y < std::min(J.H, c * chunk + chunk); ++y) {
                const int64_t base = int64_t(y) * J.W3;
                const int32_t* o = J.off + int64_t(y) * (J.V + 1);
                int64_t cnt = 0;
                for (int j = 0; j < J.n_segs; ++j) {
                    const int64_t* sg = J.segs + 4 * j;
                    const int e = int(sg[0]), k = int(sg[1]);
                    const int a = lower_bound16(J.pos + base, o[k], o[k + 1], int(3 * sg[2]));
                    const int b = lower_bound16(J.pos + base, a, o[k + 1], int(3 * sg[3]));
                    cnt += slice_run_scalar(J, y, e, k, a, b);
                }
                J.counts[y] = cnt;
            }
        });
        Py_END_ALLOW_THREADS
    }
    PyBuffer_Release(&native); PyBuffer_Release(&pos); PyBuffer_Release(&zeta); PyBuffer_Release(&off);
    PyBuffer_Release(&tex_row); PyBuffer_Release(&tex_col); PyBuffer_Release(&view1); PyBuffer_Release(&w8);
    PyBuffer_Release(&segs); PyBuffer_Release(&bounds); PyBuffer_Release(&images); PyBuffer_Release(&wmaps);
    PyBuffer_Release(&kv); PyBuffer_Release(&gh); PyBuffer_Release(&counts);
    if (!ok) return nullptr;
    Py_RETURN_NONE;
}


// ---- the nearest-mode interleave (holo_viewer.display.lenticular.Interleaver, "rows" tables) -----
// out[y, s] = src[rowpart[y, view[y, s]] + colpart[s]]: a byte copy, so any order of reads gives the
// numba kernel's result bit for bit. AVX-512: 16 subpixels at a time, the row's texel offsets
// (<= 64 views) looked up in registers (two permutes) instead of memory, then one 32-bit gather of
// the quilt bytes; a row whose gather could read past the quilt's last byte runs the scalar loop.
void gather_row_scalar(const uint8_t* src, const uint8_t* vw, const int32_t* rp, const int32_t* colpart,
                       uint8_t* o, int L, int nv) {
    for (int s = 0; s < L; ++s) o[s] = src[rp[vw[s] < nv ? vw[s] : 0] + colpart[s]];
}

#if HV_HAVE_AVX2_PATH
HV_TARGET_AVX512 void gather_row_avx512(const uint8_t* src, const uint8_t* vw, const int32_t* rp,
                                        const int32_t* colpart, uint8_t* o, int L, int nv) {
    alignas(64) int32_t tab[64] = {};
    for (int i = 0; i < nv; ++i) tab[i] = rp[i];
    const __m512i t0 = _mm512_load_si512(tab), t1 = _mm512_load_si512(tab + 16);
    const __m512i t2 = _mm512_load_si512(tab + 32), t3 = _mm512_load_si512(tab + 48);
    const __m512i bit5 = _mm512_set1_epi32(32);
    int s = 0;
    for (; s + 16 <= L; s += 16) {
        const __m512i v = _mm512_cvtepu8_epi32(_mm_loadu_si128(reinterpret_cast<const __m128i*>(vw + s)));
        const __m512i lo = _mm512_permutex2var_epi32(t0, v, t1);   // views 0..31 (index bits 0-4)
        const __m512i hi = _mm512_permutex2var_epi32(t2, v, t3);   // views 32..63
        const __m512i r = _mm512_mask_mov_epi32(lo, _mm512_test_epi32_mask(v, bit5), hi);
        const __m512i idx = _mm512_add_epi32(r, _mm512_loadu_si512(colpart + s));
        const __m512i b = _mm512_i32gather_epi32(idx, reinterpret_cast<const int*>(src), 1);
        _mm_storeu_si128(reinterpret_cast<__m128i*>(o + s), _mm512_cvtepi32_epi8(b));
    }
    gather_row_scalar(src, vw + s, rp, colpart + s, o + s, L - s, nv);
}
#endif

PyObject* gather_rows(PyObject*, PyObject* args) {
    Py_buffer src{}, view{}, rowpart{}, colpart{}, out{};
    int H, L, nv, n_threads, mode = 0;
    if (!PyArg_ParseTuple(args, "y*y*y*y*w*iiii|i", &src, &view, &rowpart, &colpart, &out, &H, &L, &nv,
                          &n_threads, &mode))
        return nullptr;
    bool ok = H >= 0 && L >= 0 && nv > 0 && nv <= 256;
    if (!ok) PyErr_SetString(PyExc_ValueError, "_slices_cpp.gather_rows: expected H, L >= 0 and 0 < views <= 256");
    ok = ok && need(view, int64_t(H) * L, "view") && need(rowpart, int64_t(H) * nv * 4, "rowpart") &&
         need(colpart, int64_t(L) * 4, "colpart") && need(out, int64_t(H) * L, "out");
    const int64_t n_src = src.len;
    const int32_t* rp_all = (const int32_t*)rowpart.buf;
    const int32_t* cp = (const int32_t*)colpart.buf;
    int64_t cmin = 0, cmax = 0;
    if (ok && L > 0) {
        cmin = *std::min_element(cp, cp + L);
        cmax = *std::max_element(cp, cp + L);
    }
    // every texel read lies inside src (the tables are the interleaver's own: checked, not trusted)
    std::vector<uint8_t> wide(size_t(ok ? H : 0), 0);
#if HV_HAVE_AVX2_PATH
    const bool avx512 = mode == 0 && nv <= 64 && cpu_has_avx512();
#else
    const bool avx512 = false;
#endif
    for (int y = 0; ok && y < H && L > 0; ++y) {
        const int32_t* rp = rp_all + int64_t(y) * nv;
        const int64_t rmin = *std::min_element(rp, rp + nv), rmax = *std::max_element(rp, rp + nv);
        ok = rmin + cmin >= 0 && rmax + cmax < n_src;
        wide[size_t(y)] = avx512 && rmax + cmax + 3 < n_src;  // a 4-byte gather at the last texel
    }
    if (!ok && !PyErr_Occurred())
        PyErr_SetString(PyExc_ValueError, "_slices_cpp.gather_rows: a texel index lies outside src");
    if (ok && H > 0 && L > 0) {
        const uint8_t* sp = (const uint8_t*)src.buf;
        const uint8_t* vp = (const uint8_t*)view.buf;
        uint8_t* op = (uint8_t*)out.buf;
        const int chunk = 16;  // rows per work item
        Py_BEGIN_ALLOW_THREADS
        parallel_for((H + chunk - 1) / chunk, std::max(1, n_threads), [&](int c) {
            for (int y = c * chunk; y < std::min(H, c * chunk + chunk); ++y) {
                const int64_t b = int64_t(y) * L;
#if HV_HAVE_AVX2_PATH
                if (wide[size_t(y)]) {
                    gather_row_avx512(sp, vp + b, rp_all + int64_t(y) * nv, cp, op + b, L, nv);
                    continue;
                }
#endif
                gather_row_scalar(sp, vp + b, rp_all + int64_t(y) * nv, cp, op + b, L, nv);
            }
        });
        Py_END_ALLOW_THREADS
    }
    PyBuffer_Release(&src); PyBuffer_Release(&view); PyBuffer_Release(&rowpart); PyBuffer_Release(&colpart);
    PyBuffer_Release(&out);
    if (!ok) return nullptr;
    Py_RETURN_NONE;
}


PyMethodDef methods[] = {
    {"scatter_slices", scatter_slices, METH_VARARGS,
     "scatter_slices(native, positions, zeta, offsets, tex_row, tex_col, view1, w8, blend, segments, bounds, "
     "reach, images, wmaps, kv, gh, iters, counts, H, W3, V, E, hv, wv, n_threads[, mode[, inner]]) -> None\n\n"
     "holo_viewer.display.slices' numba kernel (the same float32 expressions): the subpixels of the "
     "segments that an eye can receive, warped out of the eyes' slices into native. mode 1: scalar only. "
     "inner < reach: feathered over the fill."},
    {"gather_rows", gather_rows, METH_VARARGS,
     "gather_rows(src, view, rowpart, colpart, out, H, L, n_views, n_threads[, mode]) -> None\n\n"
     "out[y, s] = src[rowpart[y, view[y, s]] + colpart[s]] (uint8; holo_viewer.display.lenticular's numba "
     "kernel, bit for bit). mode 1: scalar only."},
    {"has_avx512", [](PyObject*, PyObject*) -> PyObject* { return PyBool_FromLong(cpu_has_avx512()); }, METH_NOARGS,
     "True when the CPU runs the AVX-512 path."},
    {nullptr, nullptr, 0, nullptr}};

PyModuleDef moddef = {PyModuleDef_HEAD_INIT, "_slices_cpp",
                      "C++ kernels of holo_viewer.display.slices (eye slices into the native image).", -1, methods};

}  // namespace

PyMODINIT_FUNC PyInit__slices_cpp(void) { return PyModule_Create(&moddef); }
