// Internal: how a bf16 GEMM tile's fp32 sums become C, shared by the AVX-512 BF16 micro-kernel
// (gemm_bf16.c, sums in registers) and the AMX tiles (gemm_amx.c, sums stored from the tiles), so
// both write the same bits from the same sums. x86-64 with GCC or Clang only (AVX-512F).
#ifndef MATLABER_NN_GEMM_TILE_WRITE_H
#define MATLABER_NN_GEMM_TILE_WRITE_H
#include <immintrin.h>

// Row c[0 .. n) (n <= 32) = alpha · [s0 | s1] + bias (bias: this row's, or NULL) or + beta · c
// (beta = 0 never reads c: NaN there is ignored, as BLAS does); masked past n.
__attribute__((target("avx512f"), always_inline)) static inline void mlb_gemm_tile_write_row(
    float* c, __m512 s0, __m512 s1, int n, float alpha, float beta, const float* bias) {
    const __mmask16 m0 = n >= 16 ? 0xFFFF : (__mmask16)((1u << n) - 1);
    const __mmask16 m1 = n >= 32 ? 0xFFFF : n > 16 ? (__mmask16)((1u << (n - 16)) - 1) : 0;
    const __m512 va = _mm512_set1_ps(alpha), vb = _mm512_set1_ps(beta);
    __m512 r0 = _mm512_mul_ps(va, s0), r1 = _mm512_mul_ps(va, s1);
    if (bias) {
        r0 = _mm512_add_ps(r0, _mm512_set1_ps(*bias));
        r1 = _mm512_add_ps(r1, _mm512_set1_ps(*bias));
    } else if (beta != 0) {
        r0 = _mm512_fmadd_ps(vb, _mm512_maskz_loadu_ps(m0, c), r0);
        r1 = _mm512_fmadd_ps(vb, _mm512_maskz_loadu_ps(m1, c + 16), r1);
    }
    _mm512_mask_storeu_ps(c, m0, r0);
    _mm512_mask_storeu_ps(c + 16, m1, r1);
}

#endif
