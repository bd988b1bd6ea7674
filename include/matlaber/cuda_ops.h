// The CUDA ops (src/cuda/*.cu): the same contracts as the CPU ops they mirror (nn_api.inc,
// transformer_ops.h, conv_ops.h, hashgrid.h, shade.h), over DEVICE buffers (mlb_cuda_malloc).
// Float32 in and out; GEMMs may run on fp16/bf16 tensor cores with fp32 accumulation when the
// caller asks (mlb_gemm_precision). Every op returns mlb_status: MLB_ERR_DEVICE names the file,
// line, CUDA call and CUDA's message; MLB_ERR_ARG a bad shape. Ops are asynchronous on the default
// stream (the data stays on the GPU): mlb_cuda_sync() waits and reports an execution error;
// MLB_CUDA_SYNC=1 in the environment synchronises after every launch (debugging).
// A build without the CUDA part has the same functions, each failing with "built without CUDA"
// (src/nn/no_cuda.c), so callers need no #ifdef. docs/cuda.md: what is parity-tested where.
#ifndef MATLABER_CUDA_OPS_H
#define MATLABER_CUDA_OPS_H
#include <stddef.h>
#include <stdint.h>
#include "matlaber/conv_ops.h"
#include "matlaber/device.h"
#include "matlaber/envmap.h"
#include "matlaber/error.h"
#include "matlaber/hashgrid.h"
#include "matlaber/nn.h"
#include "matlaber/shade.h"

#define MLB_OP_MAX_ROWS 128   // the per-row host coefficients of the ops axpby_rows and sds_grad
// A double as three floats that add up to it exactly (sds_grad's sum of squares): hi, mid, lo. The
// CPU op and the CUDA kernel both split with this.
#ifdef __CUDACC__
#define MLB_SUMSQ_FN static inline __host__ __device__
#else
#define MLB_SUMSQ_FN static inline
#endif
MLB_SUMSQ_FN void mlb_sumsq_split(double l, float* f) {
    f[0] = (float)l;
    double r = l - (double)f[0];
    f[1] = (float)r;
    f[2] = (float)(r - (double)f[1]);
}
MLB_SUMSQ_FN double mlb_sumsq_join(const float* f) { return ((double)f[0] + (double)f[1]) + (double)f[2]; }

// ---- context ----
// mlb_cuda_init: device.h (device selection calls it)
mlb_status mlb_cuda_sync(void);                  // cudaDeviceSynchronize, checked
mlb_status mlb_cuda_memset(void* dst, int value, size_t bytes);
mlb_status mlb_cuda_copy_d2d(void* dst, const void* src, size_t bytes);
// Fills n floats with lo + (hi - lo) u, u uniform in [0,1) from a counter hash of (seed, i): test
// and benchmark inputs drawn on the device (never zeros).
mlb_status mlb_cuda_fill_uniform(float* dst, size_t n, uint64_t seed, float lo, float hi);
// Device events around a region: begin records, end records, synchronises and returns ms.
mlb_status mlb_cuda_timer_begin(void);
mlb_status mlb_cuda_timer_end(double* ms);
// Free/total device memory in bytes.
mlb_status mlb_cuda_mem_info(size_t* free_bytes, size_t* total_bytes);

// ---- GEMM (cuBLAS) ----
// mlb_gemm_precision and its names: device.h
typedef enum { MLB_DTYPE_F32 = 0, MLB_DTYPE_F16, MLB_DTYPE_BF16 } mlb_cuda_dtype;
// Row-major C[M,N] = alpha op(A)[M,K] op(B)[K,N] + beta C with A, B of `ab_type` (C float, fp32
// accumulation; tf32 only when ab_type is F32 and prec is MLB_GEMM_TF32). trans_a: A is stored
// [K,M]; trans_b: B is stored [N,K]. lda/ldb/ldc are row strides in elements.
mlb_status mlb_cuda_gemm(int trans_a, int trans_b, int M, int N, int K, float alpha, const void* A, int lda,
                         const void* B, int ldb, float beta, float* C, int ldc, mlb_cuda_dtype ab_type,
                         mlb_gemm_precision prec);
// The strided batched form: matrix i of A at A + i stride_a (elements), likewise B and C; a stride
// of 0 reuses one matrix for every i. batch 1 is mlb_cuda_gemm.
mlb_status mlb_cuda_gemm_batched(int trans_a, int trans_b, int M, int N, int K, float alpha, const void* A, int lda,
                                 long long stride_a, const void* B, int ldb, long long stride_b, float beta, float* C,
                                 int ldc, long long stride_c, int batch, mlb_cuda_dtype ab_type,
                                 mlb_gemm_precision prec);
// float -> fp16 / bf16 (round to nearest even) on the device, n values.
mlb_status mlb_cuda_convert(void* dst, mlb_cuda_dtype dst_type, const float* src, size_t n);

// ---- the backend's ops (backend_ops.def) ----
// Declared from the op list, which gives each one's parameters once: cuda_fn(params) for an
// MLB_OP, cuda_fn(params, mlb_gemm_precision prec) for an MLB_GEMM_OP (GEMM operands at `prec`).
// The contracts are the CPU ops' of the same names; what is particular to the GPU, by name:
#define MLB_OP(name, cuda_fn, params) mlb_status cuda_fn params;
#define MLB_GEMM_OP(name, cuda_fn, params, args) mlb_status cuda_fn(MLB_ARGS params, mlb_gemm_precision prec);
#include "matlaber/backend_ops.def"
//
// linear (nn_api.inc): mlb_cuda_linear_forward out[B,OC] = in[B,C] . w[OC,C]^T + b[OC] (b may be
//   NULL); mlb_cuda_linear_backward din[B,C] += dout . w; dw[OC,C] += dout^T . in; db[OC] +=
//   sum_b dout (any may be NULL; db sums over b in order: deterministic).
// activations (nn_api.inc), the CPU's formulas in float: mlb_cuda_activation_forward (out may alias
//   in), mlb_cuda_activation_backward (din += dout * f'(in)).
// normalisation (transformer_ops.h, conv_ops.h): mlb_cuda_layernorm_forward, layer norm over the
//   last dimension, statistics two-pass in double like the CPU, one warp per row;
//   mlb_cuda_groupnorm_forward [N, C, HW], G groups, fused activation (IDENTITY or any), one block
//   per (n, g), statistics two-pass in double. Their backwards (+=), the CPU's formulas:
//   mlb_cuda_layernorm_backward din by a warp per row, dw/db by a thread per column summing rows
//   in order; mlb_cuda_groupnorm_backward by a block per (n, g), dw/db from per-image channel sums
//   (double, in scratch) added in order of n. Deterministic. mean/rstd from the forward.
// convolution and attention as tensor-core GEMMs (conv_ops.h; src/cuda/conv.cu):
//   mlb_cuda_conv2d_forward, conv2d_forward's contract (b may be NULL; out must not overlap in);
//   mlb_cuda_sdpa_forward, sdpa_forward's (q/k/v strides ldq/ldkv, Tq may differ from Tk; lse
//   [B, NH, Tq] may be NULL), the scores held for a chunk of images at a time (at most 1 GiB),
//   softmax in float. The backwards (src/cuda/conv_backward.cu): mlb_cuda_conv2d_backward and
//   mlb_cuda_sdpa_backward, conv2d_backward's and sdpa_backward's contracts (+=, any gradient may
//   be NULL; sdpa needs the forward's out and lse).
// layout and elementwise glue (src/cuda/tensor.cu; the CPU's in src/nn/backend.c): mlb_cuda_add,
//   mlb_cuda_add_channel, mlb_cuda_transpose_last2, mlb_cuda_geglu, mlb_cuda_upsample_nearest2x,
//   mlb_cuda_copy_rows (rows x width floats from src, row pitch spitch, to dst, pitch dpitch). Their
//   backwards (+=): mlb_cuda_geglu_backward per element; mlb_cuda_upsample_nearest2x_backward the
//   2x2 block sums in the CPU's order; mlb_cuda_add_channel_backward the per-channel sums by one
//   warp per (n, c) in double (a fixed order: deterministic, not the CPU's bits).
// self-attention (src/cuda/attention.cu): mlb_cuda_attention_forward, attention_forward's contract
//   without `att` (declared from the op list, `attention`), flash-style: tiles of 32 keys in shared
//   memory, an online softmax per query row (running max and sum in float), never the T x T
//   matrix. Head width hd = C / NH up to 512. fp32 at every table precision.
// embedding (src/cuda/tensor.cu): mlb_cuda_embedding, a thread per output value, the CPU's float
//   add: the CPU's bits; a token outside [0, V) gets a row of NaN (the kernel cannot fail).
// hash-grid encoding (hashgrid.h): g gives the layout (g->params is ignored: params is the device
//   copy of the table). mlb_cuda_hashgrid_forward out[N, L*F] (level-major) for x[N,3]: the same
//   float arithmetic as the CPU (no FMA contraction), so corner indices and weights agree bitwise;
//   the sums agree to rounding. mlb_cuda_hashgrid_backward: dparams += by an atomicAdd scatter (the
//   order of the float additions varies from run to run, so dparams is NOT bitwise reproducible,
//   unlike the CPU's; relative differences ~1e-6); dx += one thread per point, levels in order
//   (deterministic). Either may be NULL.
// AdamW: mlb_cuda_adam_update, adam_update's contract.
// marching tets (mt_ops.h; src/cuda/marching_tets.cu, built with -fmad=false over the CPU's maths,
//   mesh/marching_tets_math.h): mlb_cuda_marching_tets_count a thread per tet and per grid vertex
//   (its seven edge slots); mlb_cuda_scan_i32 on the device (tile sums, their scan in one block,
//   the tiles; in place allowed); mlb_cuda_marching_tets_emit a thread per grid vertex and per
//   tet, each writing its own outputs at its scanned place; mlb_cuda_marching_tets_backward a
//   thread per grid vertex gathering its edges' terms in the CPU's order (no atomics): every
//   output the CPU's bits.

// out = f(in), d1 = f'(in) (d1 may be NULL)
mlb_status mlb_cuda_activation_forward_d1(float* out, float* d1, const float* in, size_t n, mlb_activation act);
// With cuDNN in the build (src/cuda/conv_cudnn.cu) the forward and the input gradient of a
// convolution with symmetric padding run there, the rest on the GEMMs. mlb_cuda_use_cudnn(0) (or
// MLB_CUDNN=0 in the environment) sends every convolution to the GEMM path; mlb_cuda_cudnn_version
// is cuDNN's version number (e.g. 91400), 0 without it.
void mlb_cuda_use_cudnn(int on);
// mlb_cuda_sdpa_forward at fp16/bf16 with heads up to 128 wide runs fused on the tensor cores
// (src/cuda/flash_attention.cu: the scores never leave the registers); mlb_cuda_use_flash(0) (or
// MLB_FLASH=0 in the environment) sends it to the batched GEMMs and the row softmax instead.
void mlb_cuda_use_flash(int on);
// Its query rows per block, 64 (default) or 128 (or MLB_FLASH_ROWS=128): tests and the benchmark
// run both.
void mlb_cuda_flash_rows(int rows);
int mlb_cuda_cudnn_version(void);

// ---- split-sum shading (shade.h) ----
// The pre-integrated light on the device: every specular level, the irradiance cube and the
// split-sum LUT in global memory, the rotation as cos/sin.
typedef struct {
    int n_levels;
    int size[MLB_CUBE_MAX_LEVELS];
    float* spec[MLB_CUBE_MAX_LEVELS];   // device [6][size][size][3]
    int irr_size;
    float* irr;                         // device [6][irr][irr][3]
    float* lut;                         // device [256][256][2]
    float rot_cos, rot_sin;             // of light->rotation at upload
} mlb_cuda_envlight;
mlb_status mlb_cuda_envlight_upload(mlb_cuda_envlight* out, const mlb_envlight* light);
void mlb_cuda_envlight_free(mlb_cuda_envlight* l);
// mlb_shade_forward on the device, computed in float (the CPU computes in double from the same
// float texels): kd, ks, n, v [N,3], kr [N], out [N,3].
mlb_status mlb_cuda_shade_forward(float* out, const float* kd, const float* ks, const float* kr, const float* n,
                                  const float* v, int N, const mlb_cuda_envlight* light, mlb_fresnel fresnel);
// mlb_shade_backward on the device (float): accumulates (+=) into the non-NULL dkd, dks [N,3],
// dkr [N], dn, dv [N,3] from dout [N,3]; one thread per point (deterministic, no atomics).
mlb_status mlb_cuda_shade_backward(float* dkd, float* dks, float* dkr, float* dn, float* dv, const float* dout,
                                   const float* kd, const float* ks, const float* kr, const float* n, const float* v,
                                   int N, const mlb_cuda_envlight* light, mlb_fresnel fresnel);

#endif
