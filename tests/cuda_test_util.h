// Helpers for the CUDA parity tests (tests/test_cuda_*.c): skip without a GPU, move arrays to and
// from the device, and compare a GPU result with the CPU reference.
#ifndef MATLABER_CUDA_TEST_UTIL_H
#define MATLABER_CUDA_TEST_UTIL_H
#include "test.h"
#include "matlaber/cuda_ops.h"
#include "matlaber/device.h"
#include "matlaber/rng.h"

// NULL when a GPU can run the test, else why not ("no CUDA device: ...").
static inline const char* cuda_test_unavailable(void) {
    static char why[600];
    if (!mlb_cuda_compiled()) return "no CUDA device: this build has no CUDA part (built without CUDA)";
    int n = 0;
    if (mlb_cuda_probe(&n) != MLB_OK || mlb_cuda_init(0) != MLB_OK) {
        snprintf(why, sizeof why, "no CUDA device: %s", mlb_last_error());
        return why;
    }
    return NULL;
}
#define REQUIRE_GPU() do { const char* why_ = cuda_test_unavailable(); if (why_) SKIP("%s", why_); } while (0)

// A device copy of n host floats (NULL: n uninitialised floats poisoned with NaN bytes, so an
// output the kernel forgot to write shows up); NULL on failure.
static inline float* dev_floats(const float* host, size_t n) {
    void* d = NULL;
    if (mlb_cuda_malloc(&d, n * sizeof(float) + 4) != MLB_OK) return NULL;
    mlb_status st = host ? mlb_cuda_copy_to_device(d, host, n * sizeof(float)) : mlb_cuda_memset(d, 0xFF, n * sizeof(float));
    if (st != MLB_OK) { mlb_cuda_free(d); return NULL; }
    return (float*)d;
}
static inline int host_floats(float* host, const float* dev, size_t n) {
    return mlb_cuda_sync() == MLB_OK && mlb_cuda_copy_to_host(host, dev, n * sizeof(float)) == MLB_OK;
}
static inline float* host_alloc(size_t n) { return (float*)calloc(n ? n : 1, sizeof(float)); }
// The base seed of the random inputs: $MLB_TEST_SEED (scripts/gpu-parity.sh draws a fresh one per
// run and prints it) or 1; printed by every test so a failure can be replayed.
static inline uint64_t test_seed(void) {
    static uint64_t seed;
    if (!seed) {
        const char* s = getenv("MLB_TEST_SEED");
        seed = s && *s ? strtoull(s, NULL, 10) : 1;
        if (!seed) seed = 1;
        printf("  MLB_TEST_SEED=%llu\n", (unsigned long long)seed);
    }
    return seed;
}
// Uniform in [lo, hi) from Philox (seed, stream): a fresh draw for every case.
static inline void fill_uniform(float* x, size_t n, uint64_t seed, uint64_t stream, float lo, float hi) {
    for (size_t i = 0; i < n; i++) x[i] = lo + (hi - lo) * (float)mlb_rng_uniform_f64(seed, stream, i);
}

typedef struct {
    double rel_l2;     // ||gpu - cpu|| / ||cpu||
    double max_abs;    // max |gpu - cpu|
    double ref_max;    // max |cpu|
    size_t n_bad;      // NaN/Inf in the GPU output where the CPU is finite
} cmp_result;
static inline cmp_result compare(const float* gpu, const float* cpu, size_t n) {
    cmp_result r = {0, 0, 0, 0};
    double num = 0, den = 0;
    for (size_t i = 0; i < n; i++) {
        if (!isfinite(gpu[i]) && isfinite(cpu[i])) { r.n_bad++; continue; }
        double d = (double)gpu[i] - cpu[i];
        num += d * d;
        den += (double)cpu[i] * cpu[i];
        if (fabs(d) > r.max_abs) r.max_abs = fabs(d);
        if (fabs(cpu[i]) > r.ref_max) r.ref_max = fabs(cpu[i]);
    }
    r.rel_l2 = den > 0 ? sqrt(num / den) : sqrt(num);
    return r;
}
// Checks rel_l2 <= tol, no NaN, and prints the numbers.
#define CHECK_PARITY(what, gpu, cpu, n, tol) do { cmp_result r_ = compare(gpu, cpu, n); \
    printf("  %-40s rel-L2 %.2e  max-abs %.2e (|ref| max %.2e)  bound %.0e\n", what, r_.rel_l2, r_.max_abs, \
           r_.ref_max, (double)(tol)); \
    CHECK_MSG(r_.n_bad == 0, "%s: %zu non-finite GPU values", what, r_.n_bad); \
    CHECK_MSG(r_.rel_l2 <= (tol), "%s: relative L2 error %.3e over %.1e", what, r_.rel_l2, (double)(tol)); } while (0)

// Point by point (n points of dim values): a point is an outlier when a value differs by more than
// rtol times the reference's RMS. For backwards through ReLUs, whose derivative jumps at 0: a
// pre-activation that rounds to the other side of 0 in one of two implementations flips that
// point's gradient (about one point in 10^5 per layer of 16-32 units in float), so a few points
// may differ entirely while the rest agree to rounding. Checks outliers <= max_fraction * n.
#define CHECK_POINTWISE(what, got, ref, n, dim, rtol, max_fraction) do { \
    size_t n_ = (n), d_ = (dim), out_ = 0, bad_ = 0; double ss_ = 0; \
    for (size_t i_ = 0; i_ < n_ * d_; i_++) ss_ += (double)(ref)[i_] * (ref)[i_]; \
    double lim_ = (rtol) * sqrt(ss_ / (double)(n_ * d_ > 0 ? n_ * d_ : 1)); \
    for (size_t p_ = 0; p_ < n_; p_++) { int o_ = 0; \
        for (size_t c_ = 0; c_ < d_; c_++) { double g_ = (got)[p_ * d_ + c_], r_ = (ref)[p_ * d_ + c_]; \
            if (!isfinite(g_)) bad_++; else if (fabs(g_ - r_) > lim_) o_ = 1; } \
        out_ += o_; } \
    printf("  %-40s %zu of %zu points off by more than %.0e x RMS (bound %.0e of them)\n", what, out_, n_, \
           (double)(rtol), (double)(max_fraction)); \
    CHECK_MSG(bad_ == 0, "%s: %zu non-finite values", what, bad_); \
    CHECK_MSG((double)out_ <= (max_fraction) * (double)n_, "%s: %zu outlier points of %zu", what, out_, n_); } while (0)

#endif
