// Tile compositor of holo_viewer's fast splat renderer (see holo_viewer/render/fast.py).
//
// One function, composite(), blends the per-view splat records prepared by the numba
// preprocessing (fast_kernels.py: rec, box, tile lists) into the images, front to back per
// tile with early termination. Work items are (view, tile) pairs handed to std::threads
// from an atomic counter. Two code paths, chosen at run time:
//   * AVX2 + FMA (x86-64 with GCC/Clang): 8 pixels per register, branch-free blending,
//     finished rows skipped, polynomial exp;
//   * portable scalar: the same arithmetic one pixel at a time.
// Plain CPython API + buffer protocol: no build dependency beyond a C++17 compiler.
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <thread>
#include <vector>

#if (defined(__x86_64__) || defined(_M_X64)) && (defined(__GNUC__) || defined(__clang__))
#include <immintrin.h>
#define HV_HAVE_AVX2_PATH 1
#else
#define HV_HAVE_AVX2_PATH 0
#endif

namespace {

constexpr int REC = 10;            // u, v, conic A, B, C, opacity, r, g, b, q = 2 ln(opacity/threshold)
constexpr float EXP_LO = -12.8f;   // exp(x < EXP_LO) treated as exp(EXP_LO); alpha_threshold >= 1e-5

struct Job {
    const float* rec;
    const int32_t* box;
    const int64_t* off;
    const int64_t* base;
    const int32_t* ids;
    int nv, m, tile, tiles_x, tiles_y, width, height;
    float thr, cap, tmin;
    float bg[3];
    int clip;
    float* out;
    int64_t* blends;
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
    const int32_t* bx = J.box + (int64_t(v) * J.m + k) * 4;
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
                if (test < J.tmin) { b.live[p] = 0; --n_live; continue; }
                const float w = alpha * tt;
                b.R[p] += w * r[6]; b.G[p] += w * r[7]; b.B[p] += w * r[8];
                b.T[p] = test;
                ++nbl;
            }
        }
    }
    write_tile(J, v, px0, py0, pw, ph, b);
    return nbl;
}

#if HV_HAVE_AVX2_PATH
// exp(x) for x in [EXP_LO, 0]: 2^(x log2 e) = 2^n * 2^f with n = round, f in [-0.5, 0.5];
// 2^f by its degree-5 Taylor polynomial in f ln 2 (relative error < 3e-6); 2^n by adding n to
// the exponent bits. 7 floating-point operations instead of the 13 of the squaring scheme.
__attribute__((target("avx2,fma"))) inline __m256 fast_exp8(__m256 x) {
    const __m256 t = _mm256_mul_ps(_mm256_max_ps(x, _mm256_set1_ps(EXP_LO)), _mm256_set1_ps(1.4426950408889634f));
    const __m256 n = _mm256_round_ps(t, _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC);
    const __m256 f = _mm256_mul_ps(_mm256_sub_ps(t, n), _mm256_set1_ps(0.6931471805599453f));
    __m256 e = _mm256_fmadd_ps(f, _mm256_set1_ps(1.0f / 120.0f), _mm256_set1_ps(1.0f / 24.0f));
    e = _mm256_fmadd_ps(e, f, _mm256_set1_ps(1.0f / 6.0f));
    e = _mm256_fmadd_ps(e, f, _mm256_set1_ps(0.5f));
    e = _mm256_fmadd_ps(e, f, _mm256_set1_ps(1.0f));
    e = _mm256_fmadd_ps(e, f, _mm256_set1_ps(1.0f));
    const __m256i bits = _mm256_slli_epi32(_mm256_cvtps_epi32(n), 23);
    return _mm256_castsi256_ps(_mm256_add_epi32(_mm256_castps_si256(e), bits));
}

__attribute__((target("avx2,fma"))) int64_t tile_avx2(const Job& J, int v, int t, TileBuf& b) {
    const int tile = J.tile;  // multiple of 8 (checked by the caller)
    const int ty = t / J.tiles_x, tx = t % J.tiles_x;
    const int px0 = tx * tile, py0 = ty * tile;
    const int pw = std::min(tile, J.width - px0), ph = std::min(tile, J.height - py0);
    const int chunks = tile / 8;
    std::fill(b.T.begin(), b.T.end(), 1.0f);
    std::fill(b.R.begin(), b.R.end(), 0.0f);
    std::fill(b.G.begin(), b.G.end(), 0.0f);
    std::fill(b.B.begin(), b.B.end(), 0.0f);
    int n_live = 0;
    for (int y = 0; y < tile; ++y) {
        b.row_live[y] = y < ph ? pw : 0;
        n_live += b.row_live[y];
        for (int x = 0; x < tile; ++x) b.live[y * tile + x] = (y < ph && x < pw) ? -1 : 0;
    }
    // bit y set while row y has a live pixel: splats whose rows are all finished are skipped whole
    uint64_t row_mask = ph >= 64 ? ~uint64_t(0) : ((uint64_t(1) << ph) - 1);
    int64_t nbl = 0;
    const int64_t nt = int64_t(J.tiles_x) * J.tiles_y;
    const int64_t* off = J.off + int64_t(v) * (nt + 1);
    const int32_t* ids = J.ids + J.base[v];
    const __m256 lane = _mm256_setr_ps(0.f, 1.f, 2.f, 3.f, 4.f, 5.f, 6.f, 7.f);
    const __m256 zero = _mm256_setzero_ps(), one = _mm256_set1_ps(1.0f);
    const __m256 vcap = _mm256_set1_ps(J.cap), vthr = _mm256_set1_ps(J.thr), vtmin = _mm256_set1_ps(J.tmin);
    // Splat records are gathered GATHER at a time into a local buffer: independent loads overlap
    // their cache misses (the records of one tile are scattered over the view's arrays).
    constexpr int GATHER = 32;
    alignas(32) float gr[GATHER][REC];
    int32_t gb[GATHER][4];
    int n_g = 0, i_g = 0;
    for (int64_t e = off[t]; e < off[t + 1] && n_live > 0; ++e) {
        if (i_g == n_g) {
            n_g = int(std::min<int64_t>(GATHER, off[t + 1] - e));
            for (int j = 0; j < n_g; ++j) {
                const int64_t kj = int64_t(v) * J.m + ids[e + j];
                std::memcpy(gr[j], J.rec + kj * REC, sizeof(float) * REC);
                std::memcpy(gb[j], J.box + kj * 4, sizeof(int32_t) * 4);
            }
            i_g = 0;
        }
        const float* r = gr[i_g];
        const int32_t* bx = gb[i_g];
        ++i_g;
        const int x0 = std::max(bx[0], px0) - px0, x1 = std::min(bx[1], px0 + pw) - px0;
        const int y0 = std::max(bx[2], py0) - py0, y1 = std::min(bx[3], py0 + ph) - py0;
        if (x0 >= x1 || y0 >= y1) continue;
        const int nr = y1 - y0;
        if (((row_mask >> y0) & (nr >= 64 ? ~uint64_t(0) : ((uint64_t(1) << nr) - 1))) == 0) continue;
        const float u = r[0] - (float(px0) + 0.5f), vv = r[1] - (float(py0) + 0.5f);
        const __m256 ca = _mm256_set1_ps(-0.5f * r[2]);
        const float cb = r[3], cc = -0.5f * r[4];
        const __m256 op = _mm256_set1_ps(r[5]);
        const __m256 fx0 = _mm256_set1_ps(float(x0)), fx1 = _mm256_set1_ps(float(x1));
        const __m256 cr = _mm256_set1_ps(r[6]), cg = _mm256_set1_ps(r[7]), cbl = _mm256_set1_ps(r[8]);
        // One flat loop over the (row, 8-pixel chunk) pairs of the splat's box in this tile: its
        // only data-dependent branch is the exit. Mispredicted branches (per-row chunk counts,
        // skipped rows) flush the pipeline and expose the exp latency chain; masked lanes are cheaper.
        const int c0 = x0 >> 3, nc = ((x1 - 1) >> 3) - c0 + 1;
        const int n_it = (y1 - y0) * nc;
        int y = y0, c = c0;
        for (int it = 0; it < n_it; ++it) {
            const float dy = float(y) - vv;
            const __m256 lin = _mm256_set1_ps(-cb * dy), cst = _mm256_set1_ps(cc * dy * dy);
            const int p = y * tile + c * 8;
            const __m256 live = _mm256_castsi256_ps(_mm256_loadu_si256((const __m256i*)&b.live[p]));
            if (_mm256_movemask_ps(live) == 0) { ++c; const int wrap0 = c == c0 + nc; c = wrap0 ? c0 : c; y += wrap0; continue; }
            const __m256 xf = _mm256_add_ps(_mm256_set1_ps(float(c * 8)), lane);
            const __m256 dx = _mm256_sub_ps(xf, _mm256_set1_ps(u));
            const __m256 power = _mm256_fmadd_ps(_mm256_fmadd_ps(ca, dx, lin), dx, cst);
            const __m256 alpha = _mm256_min_ps(vcap, _mm256_mul_ps(op, fast_exp8(power)));
            __m256 m = _mm256_and_ps(live, _mm256_cmp_ps(power, zero, _CMP_LE_OQ));
            m = _mm256_and_ps(m, _mm256_cmp_ps(alpha, vthr, _CMP_GE_OQ));
            m = _mm256_and_ps(m, _mm256_cmp_ps(xf, fx0, _CMP_GE_OQ));
            m = _mm256_and_ps(m, _mm256_cmp_ps(xf, fx1, _CMP_LT_OQ));
            const __m256 tt = _mm256_loadu_ps(&b.T[p]);
            const __m256 test = _mm256_mul_ps(tt, _mm256_sub_ps(one, alpha));
            const __m256 fin = _mm256_and_ps(m, _mm256_cmp_ps(test, vtmin, _CMP_LT_OQ));
            const __m256 ok = _mm256_andnot_ps(fin, m);
            _mm256_storeu_si256((__m256i*)&b.live[p], _mm256_castps_si256(_mm256_andnot_ps(fin, live)));
            const int nf = __builtin_popcount(_mm256_movemask_ps(fin));
            n_live -= nf;
            const int rl = (b.row_live[y] -= nf);
            row_mask &= ~(uint64_t(rl == 0) << y);
            const __m256 w = _mm256_and_ps(ok, _mm256_mul_ps(alpha, tt));
            _mm256_storeu_ps(&b.R[p], _mm256_fmadd_ps(w, cr, _mm256_loadu_ps(&b.R[p])));
            _mm256_storeu_ps(&b.G[p], _mm256_fmadd_ps(w, cg, _mm256_loadu_ps(&b.G[p])));
            _mm256_storeu_ps(&b.B[p], _mm256_fmadd_ps(w, cbl, _mm256_loadu_ps(&b.B[p])));
            _mm256_storeu_ps(&b.T[p], _mm256_blendv_ps(tt, test, ok));
            nbl += __builtin_popcount(_mm256_movemask_ps(ok));
            // advance (branch-free: conditional moves)
            ++c;
            const int wrap = c == c0 + nc;
            c = wrap ? c0 : c;
            y += wrap;
        }
    }
    write_tile(J, v, px0, py0, pw, ph, b);
    return nbl;
}

bool cpu_has_avx2() {
    __builtin_cpu_init();
    return __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
}
#else
bool cpu_has_avx2() { return false; }
#endif

void run_jobs(const Job& J, int n_threads, bool simd) {
    const int64_t nt = int64_t(J.tiles_x) * J.tiles_y;
    const int64_t n_jobs = nt * J.nv;
    std::atomic<int64_t> next{0};
    auto worker = [&]() {
        TileBuf b(J.tile);
        for (;;) {
            const int64_t job = next.fetch_add(1);
            if (job >= n_jobs) break;
            const int v = int(job / nt), t = int(job % nt);
            int64_t nbl;
#if HV_HAVE_AVX2_PATH
            nbl = simd ? tile_avx2(J, v, t, b) : tile_scalar(J, v, t, b);
#else
            (void)simd;
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

bool need(Py_buffer& b, Py_ssize_t n_bytes, const char* name) {
    if (b.len < n_bytes) {
        PyErr_Format(PyExc_ValueError, "_splat_cpp.composite: buffer %s: expected >= %zd bytes, found %zd",
                     name, n_bytes, b.len);
        return false;
    }
    return true;
}

PyObject* composite(PyObject*, PyObject* args) {
    Py_buffer rec{}, box{}, off{}, base{}, ids{}, bg{}, out{}, blends{};
    int nv, m, tile, tiles_x, tiles_y, width, height, clip, n_threads, mode;
    double thr, cap, tmin;
    if (!PyArg_ParseTuple(args, "y*y*y*y*y*iiiiiiidddy*pw*w*ii", &rec, &box, &off, &base, &ids, &nv, &m, &tile,
                          &tiles_x, &tiles_y, &width, &height, &thr, &cap, &tmin, &bg, &clip, &out, &blends,
                          &n_threads, &mode))
        return nullptr;
    PyObject* result = nullptr;
    const int64_t nt = int64_t(tiles_x) * tiles_y;
    bool ok = nv > 0 && m >= 0 && tile > 0 && tiles_x > 0 && tiles_y > 0 && width > 0 && height > 0 &&
              int64_t(tiles_x) * tile >= width && int64_t(tiles_y) * tile >= height;
    if (!ok) PyErr_SetString(PyExc_ValueError, "_splat_cpp.composite: inconsistent sizes");
    ok = ok && need(rec, Py_ssize_t(nv) * m * REC * 4, "rec") && need(box, Py_ssize_t(nv) * m * 16, "box") &&
         need(off, Py_ssize_t(nv) * (nt + 1) * 8, "off") && need(base, Py_ssize_t(nv) * 8, "base") &&
         need(bg, 12, "bg") && need(out, Py_ssize_t(nv) * height * width * 12, "out") &&
         need(blends, Py_ssize_t(nv) * nt * 8, "blends");
    if (ok) {
        Job J{};
        J.rec = (const float*)rec.buf; J.box = (const int32_t*)box.buf; J.off = (const int64_t*)off.buf;
        J.base = (const int64_t*)base.buf; J.ids = (const int32_t*)ids.buf;
        J.nv = nv; J.m = m; J.tile = tile; J.tiles_x = tiles_x; J.tiles_y = tiles_y;
        J.width = width; J.height = height;
        J.thr = float(thr); J.cap = float(cap); J.tmin = float(tmin);
        std::memcpy(J.bg, bg.buf, 12);
        J.clip = clip; J.out = (float*)out.buf; J.blends = (int64_t*)blends.buf;
        // every tile list must stay inside ids
        const int64_t n_ids = ids.len / 4;
        for (int v = 0; v < nv && ok; ++v) {
            const int64_t last = J.base[v] + J.off[int64_t(v) * (nt + 1) + nt];
            if (J.base[v] < 0 || last > n_ids) ok = false;
        }
        if (!ok) PyErr_SetString(PyExc_ValueError, "_splat_cpp.composite: tile lists exceed ids");
        // mode: 0 = auto (AVX2 when the CPU has it), 1 = scalar, 2 = require AVX2
        const bool simd = mode != 1 && (tile % 8 == 0) && cpu_has_avx2();
        if (ok && mode == 2 && !simd) {
            PyErr_SetString(PyExc_RuntimeError, "_splat_cpp.composite: AVX2 path unavailable (CPU or tile size)");
            ok = false;
        }
        if (ok) {
            Py_BEGIN_ALLOW_THREADS
            run_jobs(J, n_threads, simd);
            Py_END_ALLOW_THREADS
            result = PyUnicode_FromString(simd ? "avx2" : "scalar");
        }
    }
    PyBuffer_Release(&rec); PyBuffer_Release(&box); PyBuffer_Release(&off); PyBuffer_Release(&base);
    PyBuffer_Release(&ids); PyBuffer_Release(&bg); PyBuffer_Release(&out); PyBuffer_Release(&blends);
    return result;
}

PyObject* has_avx2(PyObject*, PyObject*) { return PyBool_FromLong(cpu_has_avx2()); }

PyMethodDef methods[] = {
    {"composite", composite, METH_VARARGS,
     "composite(rec, box, off, base, ids, nv, m, tile, tiles_x, tiles_y, width, height, alpha_threshold, "
     "alpha_cap, t_min, bg, clip, out, blends, n_threads, mode) -> 'avx2' | 'scalar'\n\n"
     "Blend per-(view, tile) splat lists front to back into out (V, H, W, 3) float32. mode: 0 auto, "
     "1 scalar, 2 require AVX2."},
    {"has_avx2", has_avx2, METH_NOARGS, "True when the CPU runs the AVX2+FMA path."},
    {nullptr, nullptr, 0, nullptr}};

PyModuleDef moddef = {PyModuleDef_HEAD_INIT, "_splat_cpp",
                      "C++ tile compositor of holo_viewer's fast splat renderer.", -1, methods};

}  // namespace

PyMODINIT_FUNC PyInit__splat_cpp(void) { return PyModule_Create(&moddef); }
