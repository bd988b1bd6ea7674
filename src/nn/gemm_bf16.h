// Internal: the one-thread bf16 GEMM kernel that mlb_gemm_bf16 (gemm.c) runs per shard
// (gemm_bf16.c), and its operands' packed form for callers that reuse one (attention_bf16.c, the
// convolutions of conv_bf16.c, linear_bf16.c).
#ifndef MATLABER_NN_GEMM_BF16_H
#define MATLABER_NN_GEMM_BF16_H
#include <stddef.h>
#include <stdint.h>

#include "matlaber/conv_desc.h"

// Rows of the kernel's register tile (its A panels); callers cutting M do it in multiples.
#define MLB_GEMM_BF16_MR 14

// One operand: fp32 values (rounded to bf16 as they are packed), element (i, k) at
// data[offset + i·ld + k] (or transposed); packed: its whole packed form (mlb_gemm_bf16_pack), or
// NULL. With packed given, data is read only if the kernel runs out of memory, and may be NULL (a
// weight packed at load, with no fp32 copy).
// im2col (B only, not transposed): op(B) is the im2col matrix of the conv's input, one fp32 image
// [C, H, W] at data, gathered as it is packed (no buffer): row k = (c·KH + i)·KW + j, column j' =
// output pixel offset + j' (y·OW + x).
// image (with im2col, optional): the same image already in bf16 as mlb_gemm_bf16_image lays it
// out; its panels are then plain loads (the same bits as from data).
typedef struct {
    const float* data;
    size_t offset;
    int ld;
    const uint32_t* packed;
    const mlb_conv2d* im2col;
    const uint16_t* image;
} mlb_bf16_operand;

// A conv's input image [C, H, W] in bf16, zero-padded and with the columns split by their phase
// modulo the stride ([C][Hp][stride_w][Wq], Hp, Wp the padded sizes, Wq = ceil(Wp / stride_w)): each
// im2col row's pixels along an output row are then consecutive values, read with one load and no
// edge tests. mlb_gemm_bf16_image_len(cv) values per image; _image writes channels c0 .. c1 of
// image img (fp32) into out (the whole image's buffer). CPU with AVX-512 BF16 only.
size_t mlb_gemm_bf16_image_len(const mlb_conv2d* cv);
void mlb_gemm_bf16_image(const mlb_conv2d* cv, const float* img, int c0, int c1, uint16_t* out);

// Whether the CPU has AVX-512 BF16 (mlb_gemm_bf16_native() also says whether it is forced off). A
// weight packed at load has no fp32 copy: its ops and packers check this one, and run the kernel
// even when forced off.
int mlb_gemm_bf16_cpu_has(void);

// C[M,N] = alpha·op(A)·op(B) + beta·C with bf16 operands and fp32 sums, on the calling thread only.
// M, N, K >= 1. Callers with fp32 operands check mlb_gemm_bf16_native() (nn.h) first; on a CPU
// without AVX-512 BF16 an operand stored in bf16 is multiplied element by element (correct, slow).
void mlb_gemm_bf16_kernel(int ta, int tb, int M, int N, int K, float alpha, const mlb_bf16_operand* A,
                          const mlb_bf16_operand* B, float beta, float* C, int ldc);

// The same with C = alpha·op(A)·op(B) + bias[i] per row i (beta ignored, C not read): as C = bias
// with beta = 1, bit for bit, without writing C twice.
void mlb_gemm_bf16_kernel_bias(int ta, int tb, int M, int N, int K, float alpha, const mlb_bf16_operand* A,
                               const mlb_bf16_operand* B, float beta, const float* bias, float* C, int ldc);

// op(X) packed whole (side_b 0: as A, R = M rows; 1: as B, R = N columns) into
// mlb_gemm_bf16_packed_words(side_b, R, K) words, for an operand used by many products.
size_t mlb_gemm_bf16_packed_words(int side_b, int R, int K);
void mlb_gemm_bf16_pack(int side_b, int trans, int R, int K, const mlb_bf16_operand* X, uint32_t* out);

// The tile on Intel AMX (gemm_amx.c). Where mlb_gemm_bf16_amx() (nn.h) says so (the CPU has AMX-BF16,
// Linux granted its tile state, neither $MATLABER_CPU_AMX nor a test turned it off), op(A) is packed
// row-major along K in each panel ([MR][np]) and every tile runs on AMX. A thread brackets its
// tiles with _begin (the tile configuration) and _end. _tiles: gemm_bf16.c's micro_body contract
// for `panels` (1 or 2) consecutive A panels (rows m counted from the first; the second panel's
// fp32 sums at w_in / w_out + w_step) against one B panel, the block's last pairs from a_tail and
// b_tail when np is not a multiple of 16.
void mlb_gemm_amx_begin(void);
void mlb_gemm_amx_end(void);
void mlb_gemm_amx_tiles(int panels, int kp, const uint32_t* a, const uint32_t* b, const uint32_t* a_tail,
                        const uint32_t* b_tail, const float* w_in, float* w_out, size_t w_step, float* C, int ldc,
                        int m, int n, float alpha, float beta, const float* bias);
// A K block's last np % 16 pairs of `count` panels, zero-padded to one tile step each, for _tiles:
// mlb_gemm_amx_tail_words(side_b) words per panel.
size_t mlb_gemm_amx_tail_words(int side_b);
void mlb_gemm_amx_tails(int side_b, const uint32_t* panels, int count, int np, uint32_t* out);

#endif
