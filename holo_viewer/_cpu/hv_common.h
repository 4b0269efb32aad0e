// Shared by holo_viewer's compiled kernels (render/_cpu/splat.cpp, display/_cpu/slices.cpp): CPU
// feature tests, the thread pool loop and the buffer-size check. Plain C++17 + the CPython API.
#pragma once
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <algorithm>
#include <atomic>
#include <thread>
#include <vector>

#if defined(__GNUC__) || defined(__clang__)
#define HV_ALWAYS_INLINE __attribute__((always_inline))
#else
#define HV_ALWAYS_INLINE
#endif

#if (defined(__x86_64__) || defined(_M_X64)) && (defined(__GNUC__) || defined(__clang__))
#include <immintrin.h>
#define HV_HAVE_AVX2_PATH 1
#else
#define HV_HAVE_AVX2_PATH 0
#endif

#if HV_HAVE_AVX2_PATH
// GCC 12's avx512fintrin.h warns about its own _mm512_undefined_ps (a false positive)
#pragma GCC diagnostic ignored "-Wmaybe-uninitialized"
#define HV_TARGET_AVX512 __attribute__((target("avx512f,avx512vl,avx512bw,avx512dq,avx2,fma,popcnt")))
#endif

namespace hv {

#if HV_HAVE_AVX2_PATH
inline bool cpu_has_avx512() {
    __builtin_cpu_init();
    return __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512vl") &&
           __builtin_cpu_supports("avx512bw") && __builtin_cpu_supports("avx512dq") &&
           __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
}

inline bool cpu_has_avx2() {
    __builtin_cpu_init();
    return __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
}
#else
inline bool cpu_has_avx2() { return false; }
inline bool cpu_has_avx512() { return false; }
#endif

// True when buffer b holds at least n_bytes (else a ValueError naming it).
inline bool need(Py_buffer& b, Py_ssize_t n_bytes, const char* name) {
    if (b.len < n_bytes) {
        PyErr_Format(PyExc_ValueError, "buffer %s: expected >= %zd bytes, found %zd",
                     name, n_bytes, b.len);
        return false;
    }
    return true;
}

// f(i) for i in [0, n), handed to n_threads threads (the caller's included) from a counter.
template <typename F>
inline void parallel_for(int n, int n_threads, F&& f) {
    std::atomic<int> next{0};
    auto worker = [&]() {
        for (int i; (i = next.fetch_add(1)) < n;) f(i);
    };
    n_threads = std::max(1, std::min(n_threads, n));
    std::vector<std::thread> pool;
    for (int i = 1; i < n_threads; ++i) pool.emplace_back(worker);
    worker();
    for (auto& th : pool) th.join();
}

}  // namespace hv
