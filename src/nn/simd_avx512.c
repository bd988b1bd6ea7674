// simd_rows.inc in 16 fp32 lanes (AVX-512 F/BW/VL/DQ): group norm's float pass and the attention's
// row softmax. With libm's scalar expf the softmax was ~65% of a latent-phase step of the
// sd_reference tiny model, and the VAE encoder's group norm backward 2.95 s of a 9.35 s backward at
// 512² (docs/benchmarks.md).
#include <math.h>
#include <stddef.h>
#include "nn/simd_rows.h"

#ifdef MLB_SIMD_X86
#include <immintrin.h>

#define SIMD_TARGET __attribute__((target("avx512f,avx512bw,avx512vl,avx512dq")))
#define SIMD_LANES 16
#define SIMD_NAME(f) f##_avx512
typedef __m512 vf;
typedef __mmask16 vmask;
typedef __m512d vd;

static inline SIMD_TARGET vmask v_lanes(size_t n) { return n >= 16 ? (vmask)0xFFFF : (vmask)((1u << n) - 1); }
static inline SIMD_TARGET vf v_loadz(vmask k, const float* p) { return _mm512_maskz_loadu_ps(k, p); }
static inline SIMD_TARGET vf v_load_or(vmask k, const float* p, float fill) {
    return _mm512_mask_loadu_ps(_mm512_set1_ps(fill), k, p);
}
static inline SIMD_TARGET void v_store(float* p, vmask k, vf v) { _mm512_mask_storeu_ps(p, k, v); }
static inline SIMD_TARGET vf v_keep(vmask k, vf v) { return _mm512_maskz_mov_ps(k, v); }
static inline SIMD_TARGET vf v_set1(float a) { return _mm512_set1_ps(a); }
static inline SIMD_TARGET vf v_add(vf a, vf b) { return _mm512_add_ps(a, b); }
static inline SIMD_TARGET vf v_sub(vf a, vf b) { return _mm512_sub_ps(a, b); }
static inline SIMD_TARGET vf v_mul(vf a, vf b) { return _mm512_mul_ps(a, b); }
static inline SIMD_TARGET vf v_max(vf a, vf b) { return _mm512_max_ps(a, b); }
static inline SIMD_TARGET vf v_min(vf a, vf b) { return _mm512_min_ps(a, b); }
static inline SIMD_TARGET vf v_div(vf a, vf b) { return _mm512_div_ps(a, b); }
static inline SIMD_TARGET vf v_abs(vf a) { return _mm512_abs_ps(a); }
static inline SIMD_TARGET vf v_sqrt(vf a) { return _mm512_sqrt_ps(a); }
// 1 where x > 0, else 0 (NaN: 0)
static inline SIMD_TARGET vf v_step_positive(vf x) {
    return _mm512_maskz_mov_ps(_mm512_cmp_ps_mask(x, _mm512_setzero_ps(), _CMP_GT_OQ), _mm512_set1_ps(1.0f));
}
// where x < 0 the lanes of if_neg, elsewhere those of if_not
static inline SIMD_TARGET vf v_select_negative(vf x, vf if_neg, vf if_not) {
    return _mm512_mask_mov_ps(if_not, _mm512_cmp_ps_mask(x, _mm512_setzero_ps(), _CMP_LT_OQ), if_neg);
}
static inline SIMD_TARGET vf v_fmadd(vf a, vf b, vf c) { return _mm512_fmadd_ps(a, b, c); }
static inline SIMD_TARGET vf v_fmsub(vf a, vf b, vf c) { return _mm512_fmsub_ps(a, b, c); }
static inline SIMD_TARGET float v_reduce_add(vf a) { return _mm512_reduce_add_ps(a); }
static inline SIMD_TARGET float v_reduce_max(vf a) { return _mm512_reduce_max_ps(a); }
static inline SIMD_TARGET vf v_fnmadd(vf a, vf b, vf c) { return _mm512_fnmadd_ps(a, b, c); }
static inline SIMD_TARGET vf v_round(vf a) { return _mm512_roundscale_ps(a, _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC); }
static inline SIMD_TARGET vf v_scale_pow2(vf p, vf n) { return _mm512_scalef_ps(p, n); }

static inline SIMD_TARGET vd vd_zero(void) { return _mm512_setzero_pd(); }
static inline SIMD_TARGET vd vd_set1(double a) { return _mm512_set1_pd(a); }
static inline SIMD_TARGET __m512d lo_wide(vf v) { return _mm512_cvtps_pd(_mm512_castps512_ps256(v)); }
static inline SIMD_TARGET __m512d hi_wide(vf v) {
    return _mm512_cvtps_pd(_mm256_castpd_ps(_mm512_extractf64x4_pd(_mm512_castps_pd(v), 1)));
}
static inline SIMD_TARGET void vd_add_wide(vd* lo, vd* hi, vf v) {
    *lo = _mm512_add_pd(*lo, lo_wide(v));
    *hi = _mm512_add_pd(*hi, hi_wide(v));
}
static inline SIMD_TARGET void vd_fma_wide(vd* lo, vd* hi, vf a, vf b) {
    *lo = _mm512_fmadd_pd(lo_wide(a), lo_wide(b), *lo);
    *hi = _mm512_fmadd_pd(hi_wide(a), hi_wide(b), *hi);
}
static inline SIMD_TARGET void vd_sqdiff_wide(vd* lo, vd* hi, vf v, vd m, vmask k) {
    __m512d d0 = _mm512_sub_pd(lo_wide(v), m), d1 = _mm512_sub_pd(hi_wide(v), m);
    *lo = _mm512_mask3_fmadd_pd(d0, d0, *lo, (__mmask8)k);
    *hi = _mm512_mask3_fmadd_pd(d1, d1, *hi, (__mmask8)(k >> 8));
}
static inline SIMD_TARGET double vd_sum(vd lo, vd hi) { return _mm512_reduce_add_pd(_mm512_add_pd(lo, hi)); }

#include "nn/simd_rows.inc"
#endif
