// Private to src/cuda: what the GEMM-based convolution and attention files share (conv.cu,
// conv_backward.cu): operand types, scratch rounding, the convolution geometry and im2col.
#ifndef MLB_CUDA_GEMM_OPS_CUH
#define MLB_CUDA_GEMM_OPS_CUH
#include <cuda_bf16.h>
#include <cuda_fp16.h>
#include "common.cuh"
extern "C" {
#include "matlaber/conv_ops.h"
}

#define CHUNK_BYTES ((size_t)1 << 30)

template <typename T> __device__ __forceinline__ T to_operand(float x);
template <> __device__ __forceinline__ float to_operand<float>(float x) { return x; }
template <> __device__ __forceinline__ __half to_operand<__half>(float x) { return __float2half_rn(x); }
template <> __device__ __forceinline__ __nv_bfloat16 to_operand<__nv_bfloat16>(float x) { return __float2bfloat16_rn(x); }

static inline size_t round_up(size_t bytes) { return (bytes + 255) / 256 * 256; }
static inline int is_half(mlb_gemm_precision p) { return p == MLB_GEMM_FP16 || p == MLB_GEMM_BF16; }
static inline mlb_cuda_dtype operand_type(mlb_gemm_precision p) {
    return p == MLB_GEMM_FP16 ? MLB_DTYPE_F16 : p == MLB_GEMM_BF16 ? MLB_DTYPE_BF16 : MLB_DTYPE_F32;
}

// ---- conv2d ------------------------------------------------------------------------------------
struct conv_geom {
    int C, H, W, KH, KW, sh, sw, pt, pl, OH, OW;
};

// cols[b][r][p] = in[b, c, oy*sh - pt + i, ox*sw - pl + j] (0 outside), r = (c*KH + i)*KW + j,
// p = oy*OW + ox: consecutive threads take consecutive output columns, so writes coalesce.
template <typename T>
__global__ void im2col_kernel(T* cols, const float* in, int nb, conv_geom g) {
    const size_t KK = (size_t)g.KH * g.KW, CKK = g.C * KK, OHW = (size_t)g.OH * g.OW;
    const size_t n = (size_t)nb * CKK * OHW;
    for (size_t i = (size_t)blockIdx.x * blockDim.x + threadIdx.x; i < n; i += (size_t)gridDim.x * blockDim.x) {
        size_t p = i % OHW, rr = i / OHW, r = rr % CKK, b = rr / CKK;
        int oy = (int)(p / g.OW), ox = (int)(p % g.OW);
        int c = (int)(r / KK), ij = (int)(r % KK), ki = ij / g.KW, kj = ij % g.KW;
        int iy = oy * g.sh - g.pt + ki, ix = ox * g.sw - g.pl + kj;
        float v = 0.0f;
        if (iy >= 0 && iy < g.H && ix >= 0 && ix < g.W) v = in[((b * g.C + c) * g.H + iy) * g.W + ix];
        cols[i] = to_operand<T>(v);
    }
}

static inline conv_geom conv_geom_of(const mlb_conv2d* cv) {
    conv_geom g = {cv->C, cv->H, cv->W, cv->KH, cv->KW, cv->stride_h, cv->stride_w, cv->pad_top, cv->pad_left,
                   mlb_conv2d_out_h(cv), mlb_conv2d_out_w(cv)};
    return g;
}
// cols [nb][C*KH*KW][OH*OW] of dt from in [nb, C, H, W] (zeros outside)
mlb_status mlb_cuda_im2col(mlb_cuda_dtype dt, void* cols, const float* in, int nb, const conv_geom& g);
// out [B, NH, T, hd] of dt from in [B, T, ld] (head h at column h*hd)
mlb_status mlb_cuda_split_heads(mlb_cuda_dtype dt, void* out, const float* in, int B, int T_, int NH, int hd, int ld);
// Attention fused on the tensor cores (flash_attention.cu): sdpa_forward's contract at fp16/bf16.
// usable: the switch is on (mlb_cuda_use_flash, $MLB_FLASH), prec is fp16/bf16, hd <= 128 and the
// GPU has bf16 tensor cores (sm_80 on).
int mlb_cuda_flash_usable(int B, int Tq, int hd, int NH, mlb_gemm_precision prec);
mlb_status mlb_cuda_flash_sdpa(float* out, float* lse, const float* q, const float* k, const float* v, int B, int Tq,
                               int Tk, int C, int NH, int ldq, int ldkv, mlb_gemm_precision prec);
#endif
