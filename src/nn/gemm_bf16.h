// Internal: the one-thread bf16 GEMM kernel that mlb_gemm_bf16 (gemm.c) runs per shard
// (gemm_bf16.c), and its operands' packed form for callers that reuse one (attention_bf16.c).
#ifndef MATLABER_NN_GEMM_BF16_H
#define MATLABER_NN_GEMM_BF16_H
#include <stddef.h>
#include <stdint.h>

#include "matlaber/conv_ops.h"

// One operand: fp32 values (rounded to bf16 as they are packed) or values stored in bf16 (uint16_t,
// the top half of the fp32 bits, as mlb_bf16_from_f32 rounds them: then the same products bit for
// bit), element (i, k) at data[offset + i·ld + k] (or transposed); packed: its whole packed form
// (mlb_gemm_bf16_pack), then data is read only if the kernel runs out of memory, or NULL.
// im2col (B only, not transposed): op(B) is the im2col matrix of the conv's input, one fp32 image
// [C, H, W] at data, gathered as it is packed (no buffer): row k = (c·KH + i)·KW + j, column j' =
// output pixel offset + j' (y·OW + x); ld >= the columns used, is_bf16 0.
typedef struct {
    const void* data;
    int is_bf16;
    size_t offset;
    int ld;
    const uint32_t* packed;
    const mlb_conv2d* im2col;
} mlb_bf16_operand;

// C[M,N] = alpha·op(A)·op(B) + beta·C with bf16 operands and fp32 sums, on the calling thread only.
// M, N, K >= 1. Callers with fp32 operands check mlb_gemm_bf16_native() (nn.h) first; on a CPU
// without AVX-512 BF16 an operand stored in bf16 is multiplied element by element (correct, slow).
void mlb_gemm_bf16_kernel(int ta, int tb, int M, int N, int K, float alpha, const mlb_bf16_operand* A,
                          const mlb_bf16_operand* B, float beta, float* C, int ldc);

// op(X) packed whole (side_b 0: as A, R = M rows; 1: as B, R = N columns) into
// mlb_gemm_bf16_packed_words(side_b, R, K) words, for an operand used by many products.
size_t mlb_gemm_bf16_packed_words(int side_b, int R, int K);
void mlb_gemm_bf16_pack(int side_b, int trans, int R, int K, const mlb_bf16_operand* X, uint32_t* out);

#endif
