// Internal: the one-thread bf16 GEMM that mlb_gemm_bf16 (gemm.c) runs per shard (gemm_bf16.c).
#ifndef MATLABER_NN_GEMM_BF16_H
#define MATLABER_NN_GEMM_BF16_H

// C[M,N] = alpha·op(A)·op(B) + beta·C with bf16 operands and fp32 sums, on the calling thread only.
// Only when mlb_gemm_bf16_native() (nn.h) is 1. M, N, K >= 1.
void mlb_gemm_bf16_serial(int ta, int tb, int M, int N, int K, float alpha, const float* A, int lda, const float* B,
                          int ldb, float beta, float* C, int ldc);

#endif
