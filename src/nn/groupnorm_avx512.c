// Group norm with an optional fused SiLU, forward and backward, for one group at a time in 16 fp32
// lanes (AVX-512): the loops of groupnorm_forward / groupnorm_backward (conv_ops.c) without their
// scalar expf and per-element double conversions, which made the SD VAE encoder's group norm
// backward 2.95 s of a 9.35 s backward at 512² (docs/benchmarks.md).
//
// Same arithmetic as the scalar loops, in a fixed lane order: the group's mean and variance (two
// passes) and the per-channel sums in double, 8 lanes each; xhat, the affine and the activation in
// fp32, the sigmoid through the vectorised exp of avx512_math.h. One group is one call on one
// thread, so the result does not depend on the thread count.
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include "nn/groupnorm_avx512.h"

#if defined(__x86_64__) && defined(__GNUC__) && (__GNUC__ >= 10 || defined(__clang__))
#define MLB_GN_KERNEL 1
#include "nn/avx512_math.h"
#endif

#ifdef MLB_GN_KERNEL
// acc += the 16 lanes of v widened to double (lanes outside k are zero in v).
MLB_AVX512_TARGET static inline void add_wide(__m512d* lo, __m512d* hi, __m512 v) {
    *lo = _mm512_add_pd(*lo, _mm512_cvtps_pd(_mm512_castps512_ps256(v)));
    *hi = _mm512_add_pd(*hi, _mm512_cvtps_pd(_mm256_castpd_ps(_mm512_extractf64x4_pd(_mm512_castps_pd(v), 1))));
}

// acc += a·b lane by lane in double.
MLB_AVX512_TARGET static inline void fma_wide(__m512d* lo, __m512d* hi, __m512 a, __m512 b) {
    __m256 ah = _mm256_castpd_ps(_mm512_extractf64x4_pd(_mm512_castps_pd(a), 1));
    __m256 bh = _mm256_castpd_ps(_mm512_extractf64x4_pd(_mm512_castps_pd(b), 1));
    *lo = _mm512_fmadd_pd(_mm512_cvtps_pd(_mm512_castps512_ps256(a)), _mm512_cvtps_pd(_mm512_castps512_ps256(b)), *lo);
    *hi = _mm512_fmadd_pd(_mm512_cvtps_pd(ah), _mm512_cvtps_pd(bh), *hi);
}

MLB_AVX512_TARGET static inline double sum_wide(__m512d lo, __m512d hi) {
    return _mm512_reduce_add_pd(_mm512_add_pd(lo, hi));
}

// The activation and its derivative at y (16 lanes).
MLB_AVX512_TARGET static inline __m512 act(__m512 y, int silu) {
    return silu ? _mm512_mul_ps(y, mlb_sigmoid_ps(y)) : y;
}
MLB_AVX512_TARGET static inline __m512 act_d1(__m512 y, int silu) {
    if (!silu) return _mm512_set1_ps(1.0f);
    __m512 sg = mlb_sigmoid_ps(y), one = _mm512_set1_ps(1.0f);   // sigma (1 + y (1 - sigma))
    return _mm512_mul_ps(sg, _mm512_fmadd_ps(y, _mm512_sub_ps(one, sg), one));
}

MLB_AVX512_TARGET void mlb_groupnorm_forward_group(float* out, double* mean, double* rstd, const float* x,
                                                   const float* w, const float* b, int Cg, int HW, float eps,
                                                   int silu) {
    const size_t M = (size_t)Cg * HW;
    __m512d lo = _mm512_setzero_pd(), hi = _mm512_setzero_pd();
    for (size_t i = 0; i < M; i += 16) add_wide(&lo, &hi, _mm512_maskz_loadu_ps(mlb_lanes16(M - i), x + i));
    const double m = M ? sum_wide(lo, hi) / (double)M : 0;
    const __m512d vm = _mm512_set1_pd(m);
    lo = hi = _mm512_setzero_pd();
    for (size_t i = 0; i < M; i += 16) {
        __mmask16 k = mlb_lanes16(M - i);
        __m512 v = _mm512_maskz_loadu_ps(k, x + i);
        __m512d d0 = _mm512_sub_pd(_mm512_cvtps_pd(_mm512_castps512_ps256(v)), vm);
        __m512d d1 = _mm512_sub_pd(
            _mm512_cvtps_pd(_mm256_castpd_ps(_mm512_extractf64x4_pd(_mm512_castps_pd(v), 1))), vm);
        lo = _mm512_mask3_fmadd_pd(d0, d0, lo, (__mmask8)k);
        hi = _mm512_mask3_fmadd_pd(d1, d1, hi, (__mmask8)(k >> 8));
    }
    const double var = M ? sum_wide(lo, hi) / (double)M : 0, r = 1.0 / sqrt(var + (double)eps);
    // x - m as (x - m_hi) - m_lo with m = m_hi + m_lo: the first difference is exact for x near m, so
    // xhat keeps the double mean's accuracy where a large mean meets a small spread
    const float m_hi = (float)m;
    const __m512 fm = _mm512_set1_ps(m_hi), fm_lo = _mm512_set1_ps((float)(m - (double)m_hi)),
                 fr = _mm512_set1_ps((float)r);
    for (int cc = 0; cc < Cg; cc++) {
        const __m512 vw = _mm512_set1_ps(w ? w[cc] : 1.0f), vb = _mm512_set1_ps(b ? b[cc] : 0.0f);
        const float* xc = x + (size_t)cc * HW;
        float* oc = out + (size_t)cc * HW;
        for (int p = 0; p < HW; p += 16) {
            __mmask16 k = mlb_lanes16((size_t)(HW - p));
            __m512 xh = _mm512_mul_ps(_mm512_sub_ps(_mm512_sub_ps(_mm512_maskz_loadu_ps(k, xc + p), fm), fm_lo), fr);
            _mm512_mask_storeu_ps(oc + p, k, act(_mm512_fmadd_ps(xh, vw, vb), silu));
        }
    }
    *mean = m;
    *rstd = r;
}

MLB_AVX512_TARGET void mlb_groupnorm_backward_group(float* dx, double* part, const float* dout, const float* x,
                                                    const float* w, const float* b, float mean, float rstd, int Cg,
                                                    int HW, int silu) {
    const size_t M = (size_t)Cg * HW;
    const __m512 fm = _mm512_set1_ps(mean), fr = _mm512_set1_ps(rstd);
    double s1 = 0, s2 = 0;   // sums of gy·w and gy·w·xhat over the group
    for (int cc = 0; cc < Cg; cc++) {
        const float wc = w ? w[cc] : 1.0f;
        const __m512 vw = _mm512_set1_ps(wc), vb = _mm512_set1_ps(b ? b[cc] : 0.0f);
        const float* xc = x + (size_t)cc * HW;
        const float* dc = dout + (size_t)cc * HW;
        __m512d pw_lo = _mm512_setzero_pd(), pw_hi = pw_lo, pb_lo = pw_lo, pb_hi = pw_lo;
        for (int p = 0; p < HW; p += 16) {
            __mmask16 k = mlb_lanes16((size_t)(HW - p));
            __m512 xh = _mm512_mul_ps(_mm512_sub_ps(_mm512_maskz_loadu_ps(k, xc + p), fm), fr);
            __m512 gy = _mm512_mul_ps(_mm512_maskz_loadu_ps(k, dc + p), act_d1(_mm512_fmadd_ps(xh, vw, vb), silu));
            fma_wide(&pw_lo, &pw_hi, gy, xh);   // gy is zero outside k
            add_wide(&pb_lo, &pb_hi, gy);
        }
        const double pw = sum_wide(pw_lo, pw_hi), pb = sum_wide(pb_lo, pb_hi);
        s1 += pb * (double)wc;
        s2 += pw * (double)wc;
        if (part) { part[2 * cc] = pw; part[2 * cc + 1] = pb; }
    }
    if (!dx) return;
    const __m512 mg = _mm512_set1_ps((float)(M ? s1 / (double)M : 0)), mgx = _mm512_set1_ps((float)(M ? s2 / (double)M : 0));
    for (int cc = 0; cc < Cg; cc++) {
        const __m512 vw = _mm512_set1_ps(w ? w[cc] : 1.0f), vb = _mm512_set1_ps(b ? b[cc] : 0.0f);
        const float* xc = x + (size_t)cc * HW;
        const float* dc = dout + (size_t)cc * HW;
        float* dxc = dx + (size_t)cc * HW;
        for (int p = 0; p < HW; p += 16) {
            __mmask16 k = mlb_lanes16((size_t)(HW - p));
            __m512 xh = _mm512_mul_ps(_mm512_sub_ps(_mm512_maskz_loadu_ps(k, xc + p), fm), fr);
            __m512 gy = _mm512_mul_ps(_mm512_maskz_loadu_ps(k, dc + p), act_d1(_mm512_fmadd_ps(xh, vw, vb), silu));
            __m512 t = _mm512_sub_ps(_mm512_fmsub_ps(gy, vw, mg), _mm512_mul_ps(xh, mgx));   // gy w - mg - xh mgx
            _mm512_mask_storeu_ps(dxc + p, k, _mm512_fmadd_ps(fr, t, _mm512_maskz_loadu_ps(k, dxc + p)));
        }
    }
}
#else
void mlb_groupnorm_forward_group(float* out, double* mean, double* rstd, const float* x, const float* w,
                                 const float* b, int Cg, int HW, float eps, int silu) {
    (void)out; (void)mean; (void)rstd; (void)x; (void)w; (void)b; (void)Cg; (void)HW; (void)eps; (void)silu;
}
void mlb_groupnorm_backward_group(float* dx, double* part, const float* dout, const float* x, const float* w,
                                  const float* b, float mean, float rstd, int Cg, int HW, int silu) {
    (void)dx; (void)part; (void)dout; (void)x; (void)w; (void)b; (void)mean; (void)rstd; (void)Cg; (void)HW;
    (void)silu;
}
#endif
