// simd_rows.inc in 8 fp32 lanes (AVX2 + FMA): group norm's float pass and the attention's row
// softmax on CPUs without AVX-512, where the scalar loops and libm's expf were ~20% of a `tiny`
// generation (docs/benchmarks.md). The exp and sigmoid give the 16-lane kernels' bits lane for lane;
// the sums are split over other lanes, so results differ from the 16-lane kernels by rounding.
#include <math.h>
#include <stddef.h>
#include "nn/simd_rows.h"

#ifdef MLB_SIMD_X86
#include <immintrin.h>

#define SIMD_TARGET __attribute__((target("avx2,fma")))
#define SIMD_LANES 8
#define SIMD_NAME(f) f##_avx2
typedef __m256 vf;
typedef __m256i vmask;
typedef __m256d vd;

static inline SIMD_TARGET vmask v_lanes(size_t n) {
    return _mm256_cmpgt_epi32(_mm256_set1_epi32(n >= 8 ? 8 : (int)n), _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7));
}
static inline SIMD_TARGET vf v_loadz(vmask k, const float* p) { return _mm256_maskload_ps(p, k); }
static inline SIMD_TARGET vf v_load_or(vmask k, const float* p, float fill) {
    return _mm256_blendv_ps(_mm256_set1_ps(fill), _mm256_maskload_ps(p, k), _mm256_castsi256_ps(k));
}
static inline SIMD_TARGET void v_store(float* p, vmask k, vf v) { _mm256_maskstore_ps(p, k, v); }
static inline SIMD_TARGET vf v_keep(vmask k, vf v) { return _mm256_and_ps(_mm256_castsi256_ps(k), v); }
static inline SIMD_TARGET vf v_set1(float a) { return _mm256_set1_ps(a); }
static inline SIMD_TARGET vf v_add(vf a, vf b) { return _mm256_add_ps(a, b); }
static inline SIMD_TARGET vf v_sub(vf a, vf b) { return _mm256_sub_ps(a, b); }
static inline SIMD_TARGET vf v_mul(vf a, vf b) { return _mm256_mul_ps(a, b); }
static inline SIMD_TARGET vf v_max(vf a, vf b) { return _mm256_max_ps(a, b); }
static inline SIMD_TARGET vf v_min(vf a, vf b) { return _mm256_min_ps(a, b); }
static inline SIMD_TARGET vf v_div(vf a, vf b) { return _mm256_div_ps(a, b); }
static inline SIMD_TARGET vf v_abs(vf a) { return _mm256_andnot_ps(_mm256_set1_ps(-0.0f), a); }
static inline SIMD_TARGET vf v_sqrt(vf a) { return _mm256_sqrt_ps(a); }
// 1 where x > 0, else 0 (NaN: 0)
static inline SIMD_TARGET vf v_step_positive(vf x) {
    return _mm256_and_ps(_mm256_cmp_ps(x, _mm256_setzero_ps(), _CMP_GT_OQ), _mm256_set1_ps(1.0f));
}
// where x < 0 the lanes of if_neg, elsewhere those of if_not
static inline SIMD_TARGET vf v_select_negative(vf x, vf if_neg, vf if_not) {
    return _mm256_blendv_ps(if_not, if_neg, _mm256_cmp_ps(x, _mm256_setzero_ps(), _CMP_LT_OQ));
}
static inline SIMD_TARGET vf v_fmadd(vf a, vf b, vf c) { return _mm256_fmadd_ps(a, b, c); }
static inline SIMD_TARGET vf v_fmsub(vf a, vf b, vf c) { return _mm256_fmsub_ps(a, b, c); }
static inline SIMD_TARGET float v_reduce_add(vf a) {
    __m128 s = _mm_add_ps(_mm256_castps256_ps128(a), _mm256_extractf128_ps(a, 1));
    s = _mm_add_ps(s, _mm_movehl_ps(s, s));
    return _mm_cvtss_f32(_mm_add_ss(s, _mm_movehdup_ps(s)));
}
static inline SIMD_TARGET float v_reduce_max(vf a) {
    __m128 s = _mm_max_ps(_mm256_castps256_ps128(a), _mm256_extractf128_ps(a, 1));
    s = _mm_max_ps(s, _mm_movehl_ps(s, s));
    return _mm_cvtss_f32(_mm_max_ss(s, _mm_movehdup_ps(s)));
}
static inline SIMD_TARGET vf v_fnmadd(vf a, vf b, vf c) { return _mm256_fnmadd_ps(a, b, c); }
static inline SIMD_TARGET vf v_round(vf a) { return _mm256_round_ps(a, _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC); }
// 2^n built in the exponent field, applied as two factors 2^(n/2) (each >= 2^-75: normal) so that a
// subnormal result is rounded once, as VSCALEFPS rounds it: the 16-lane kernels' bits
static inline SIMD_TARGET __m256 pow2i(__m256i n) {
    return _mm256_castsi256_ps(_mm256_slli_epi32(_mm256_add_epi32(n, _mm256_set1_epi32(127)), 23));
}
static inline SIMD_TARGET vf v_scale_pow2(vf p, vf n) {
    const __m256i ni = _mm256_cvtps_epi32(n), n1 = _mm256_srai_epi32(ni, 1);   // n1 = floor(n / 2)
    return _mm256_mul_ps(_mm256_mul_ps(p, pow2i(n1)), pow2i(_mm256_sub_epi32(ni, n1)));
}

static inline SIMD_TARGET vd vd_zero(void) { return _mm256_setzero_pd(); }
static inline SIMD_TARGET vd vd_set1(double a) { return _mm256_set1_pd(a); }
static inline SIMD_TARGET vd lo_wide(vf v) { return _mm256_cvtps_pd(_mm256_castps256_ps128(v)); }
static inline SIMD_TARGET vd hi_wide(vf v) { return _mm256_cvtps_pd(_mm256_extractf128_ps(v, 1)); }
static inline SIMD_TARGET void vd_add_wide(vd* lo, vd* hi, vf v) {
    *lo = _mm256_add_pd(*lo, lo_wide(v));
    *hi = _mm256_add_pd(*hi, hi_wide(v));
}
static inline SIMD_TARGET void vd_fma_wide(vd* lo, vd* hi, vf a, vf b) {
    *lo = _mm256_fmadd_pd(lo_wide(a), lo_wide(b), *lo);
    *hi = _mm256_fmadd_pd(hi_wide(a), hi_wide(b), *hi);
}
static inline SIMD_TARGET void vd_sqdiff_wide(vd* lo, vd* hi, vf v, vd m, vmask k) {
    // the float lane mask widened to the double lanes: each 32-bit all-ones lane becomes 64 bits
    const vd k0 = _mm256_castsi256_pd(_mm256_cvtepi32_epi64(_mm256_castsi256_si128(k)));
    const vd k1 = _mm256_castsi256_pd(_mm256_cvtepi32_epi64(_mm256_extracti128_si256(k, 1)));
    vd d0 = _mm256_and_pd(_mm256_sub_pd(lo_wide(v), m), k0), d1 = _mm256_and_pd(_mm256_sub_pd(hi_wide(v), m), k1);
    *lo = _mm256_fmadd_pd(d0, d0, *lo);
    *hi = _mm256_fmadd_pd(d1, d1, *hi);
}
static inline SIMD_TARGET double vd_sum(vd lo, vd hi) {
    vd s = _mm256_add_pd(lo, hi);
    __m128d t = _mm_add_pd(_mm256_castpd256_pd128(s), _mm256_extractf128_pd(s, 1));
    return _mm_cvtsd_f64(_mm_add_sd(t, _mm_unpackhi_pd(t, t)));
}

#include "nn/simd_rows.inc"
#endif
