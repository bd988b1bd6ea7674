// Internal: the one-thread bf16 GEMM that mlb_gemm_bf16 (gemm.c) runs per shard (gemm_bf16.c).
#ifndef MATLABER_NN_GEMM_BF16_H
#define MATLABER_NN_GEMM_BF16_H
#include <stddef.h>
#include <stdint.h>

// C[M,N] = alpha·op(A)·op(B) + beta·C with bf16 operands and fp32 sums, on the calling thread only.
// Only when mlb_gemm_bf16_native() (nn.h) is 1. M, N, K >= 1.
void mlb_gemm_bf16_serial(int ta, int tb, int M, int N, int K, float alpha, const float* A, int lda, const float* B,
                          int ldb, float beta, float* C, int ldc);

// The same with op(A) and/or op(B) given already packed (NULL: packed here, per K block), so an
// operand used by many products is converted once: mlb_gemm_bf16_pack(0, ta, M, K, A, lda, ..) for
// A, mlb_gemm_bf16_pack(1, tb, N, K, B, ldb, ..) for B, into mlb_gemm_bf16_packed_words(side_b, M or
// N, K) words. A and B are still passed: they are read only where no packed form is given, and by
// the fp32 fallback if the kernel's tiles cannot be allocated.
size_t mlb_gemm_bf16_packed_words(int side_b, int R, int K);
void mlb_gemm_bf16_pack(int side_b, int trans, int R, int K, const float* X, int ld, uint32_t* out);
void mlb_gemm_bf16_serial_packed(int ta, int tb, int M, int N, int K, float alpha, const float* A, int lda,
                                 const uint32_t* A_packed, const float* B, int ldb, const uint32_t* B_packed,
                                 float beta, float* C, int ldc);

#endif
