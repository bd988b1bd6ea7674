// Internal: the 8-lane (AVX2 + FMA) twins of avx512_math.h's exp and sigmoid, for CPUs without
// AVX-512 (simd_avx2.c). Include only from a file that defines its functions under MLB_AVX2_TARGET,
// on x86-64 with GCC >= 10 / clang.
//
// Lane for lane the same bits as the AVX-512 versions: the same reduction and polynomial, VROUNDPS
// for VRNDSCALEPS, and 2^n applied as two exact power-of-two factors (n down to -145 for x >= -100:
// each half >= -73 is a normal float) so that a subnormal result is rounded once, as VSCALEFPS does.
#ifndef MATLABER_NN_AVX2_MATH_H
#define MATLABER_NN_AVX2_MATH_H
#include <immintrin.h>

#define MLB_AVX2_TARGET __attribute__((target("avx2,fma")))

// 2^n for integral n in [-126, 127] (float lanes holding integers), built in the exponent field.
MLB_AVX2_TARGET static inline __m256 mlb_pow2i_ps(__m256i n) {
    return _mm256_castsi256_ps(_mm256_slli_epi32(_mm256_add_epi32(n, _mm256_set1_epi32(127)), 23));
}

// e^x for x <= 0, 8 lanes (avx512_math.h's mlb_exp_nonpositive_ps).
MLB_AVX2_TARGET static inline __m256 mlb_exp_nonpositive_ps8(__m256 x) {
    const __m256 log2e = _mm256_set1_ps(1.44269504088896341f);
    const __m256 ln2_hi = _mm256_set1_ps(0.693145751953125f), ln2_lo = _mm256_set1_ps(1.428606765330187e-6f);
    x = _mm256_max_ps(x, _mm256_set1_ps(-100.0f));
    __m256 n = _mm256_round_ps(_mm256_mul_ps(x, log2e), _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC);
    __m256 r = _mm256_fnmadd_ps(n, ln2_hi, x);
    r = _mm256_fnmadd_ps(n, ln2_lo, r);
    __m256 p = _mm256_set1_ps(1.0f / 720);
    p = _mm256_fmadd_ps(p, r, _mm256_set1_ps(1.0f / 120));
    p = _mm256_fmadd_ps(p, r, _mm256_set1_ps(1.0f / 24));
    p = _mm256_fmadd_ps(p, r, _mm256_set1_ps(1.0f / 6));
    p = _mm256_fmadd_ps(p, r, _mm256_set1_ps(0.5f));
    p = _mm256_fmadd_ps(p, r, _mm256_set1_ps(1.0f));
    p = _mm256_fmadd_ps(p, r, _mm256_set1_ps(1.0f));
    const __m256i ni = _mm256_cvtps_epi32(n), n1 = _mm256_srai_epi32(ni, 1);   // n1 = floor(n / 2)
    return _mm256_mul_ps(_mm256_mul_ps(p, mlb_pow2i_ps(n1)), mlb_pow2i_ps(_mm256_sub_epi32(ni, n1)));
}

// The logistic sigma(y), from the side whose exponential cannot overflow (mlb_sigmoid_ps).
MLB_AVX2_TARGET static inline __m256 mlb_sigmoid_ps8(__m256 y) {
    const __m256 abs_y = _mm256_andnot_ps(_mm256_set1_ps(-0.0f), y);
    __m256 e = mlb_exp_nonpositive_ps8(_mm256_sub_ps(_mm256_setzero_ps(), abs_y));
    __m256 neg = _mm256_cmp_ps(y, _mm256_setzero_ps(), _CMP_LT_OQ);
    __m256 num = _mm256_blendv_ps(_mm256_set1_ps(1.0f), e, neg);
    return _mm256_div_ps(num, _mm256_add_ps(_mm256_set1_ps(1.0f), e));
}

// The mask of the first n (< 8 is a tail; >= 8 all) lanes, all ones in each lane taken.
MLB_AVX2_TARGET static inline __m256i mlb_lanes8(size_t n) {
    const int k = n >= 8 ? 8 : (int)n;
    return _mm256_cmpgt_epi32(_mm256_set1_epi32(k), _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7));
}
#endif
