// Internal: vectorised fp32 math shared by the CPU's AVX-512 kernels (attention_bf16.c,
// groupnorm_avx512.c). Include only from a file that defines its functions under
// __attribute__((target(...))) with at least avx512f and avx512dq, on x86-64 with GCC >= 10 / clang.
#ifndef MATLABER_NN_AVX512_MATH_H
#define MATLABER_NN_AVX512_MATH_H
#include <immintrin.h>

#define MLB_AVX512_TARGET __attribute__((target("avx512f,avx512bw,avx512vl,avx512dq")))

// e^x for x <= 0, 16 lanes: x = n·ln2 + r with |r| <= ln2/2, e^r by its Taylor polynomial to r^6
// (truncation < 1.3e-7 relative), times 2^n by VSCALEFPS. Below -100 the result is 0 (e^-100 is far
// under fp32's normal range).
MLB_AVX512_TARGET static inline __m512 mlb_exp_nonpositive_ps(__m512 x) {
    const __m512 log2e = _mm512_set1_ps(1.44269504088896341f);
    const __m512 ln2_hi = _mm512_set1_ps(0.693145751953125f), ln2_lo = _mm512_set1_ps(1.428606765330187e-6f);
    x = _mm512_max_ps(x, _mm512_set1_ps(-100.0f));
    __m512 n = _mm512_roundscale_ps(_mm512_mul_ps(x, log2e), _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC);
    __m512 r = _mm512_fnmadd_ps(n, ln2_hi, x);
    r = _mm512_fnmadd_ps(n, ln2_lo, r);
    __m512 p = _mm512_set1_ps(1.0f / 720);
    p = _mm512_fmadd_ps(p, r, _mm512_set1_ps(1.0f / 120));
    p = _mm512_fmadd_ps(p, r, _mm512_set1_ps(1.0f / 24));
    p = _mm512_fmadd_ps(p, r, _mm512_set1_ps(1.0f / 6));
    p = _mm512_fmadd_ps(p, r, _mm512_set1_ps(0.5f));
    p = _mm512_fmadd_ps(p, r, _mm512_set1_ps(1.0f));
    p = _mm512_fmadd_ps(p, r, _mm512_set1_ps(1.0f));
    return _mm512_scalef_ps(p, n);
}

// The logistic sigma(y) = 1 / (1 + e^-y), from the side whose exponential cannot overflow:
// e = e^-|y|, sigma = 1 / (1 + e) for y >= 0 and e / (1 + e) below.
MLB_AVX512_TARGET static inline __m512 mlb_sigmoid_ps(__m512 y) {
    __m512 e = mlb_exp_nonpositive_ps(_mm512_sub_ps(_mm512_setzero_ps(), _mm512_abs_ps(y)));
    __mmask16 neg = _mm512_cmp_ps_mask(y, _mm512_setzero_ps(), _CMP_LT_OQ);
    __m512 num = _mm512_mask_mov_ps(_mm512_set1_ps(1.0f), neg, e);
    return _mm512_div_ps(num, _mm512_add_ps(_mm512_set1_ps(1.0f), e));
}

// The mask of the first n (< 16 is a tail; >= 16 all) lanes.
static inline __mmask16 mlb_lanes16(size_t n) { return n >= 16 ? (__mmask16)0xFFFF : (__mmask16)((1u << n) - 1); }

#endif
