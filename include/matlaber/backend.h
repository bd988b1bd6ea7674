// One dispatch point per op. A model's forward is written once against this table and runs on the
// device whose table it is given (docs/cuda.md "Dispatch"): every buffer it passes lives on that
// device, allocated through the table, so the data stays there from the first op to the last.
//
//   const mlb_backend* be = mlb_backend_for(MLB_DEVICE_CUDA, MLB_GEMM_TF32);
//   float* x;  MLB_TRY(be->alloc(&x, n));  MLB_TRY(be->upload(x, host, n));
//   MLB_TRY(be->conv2d(be, y, x, w, b, &cv));  ...  MLB_TRY(be->download(host, y, m));
//
// The CPU table calls the CPU ops of nn_api.inc, transformer_ops.h and conv_ops.h, in the order
// and with the arithmetic the models used before the table existed, so CPU results are bitwise
// unchanged. The CPU's bf16 table is the same but for the linear and conv GEMMs (forward and
// backward) and the attention (forward and backward), which take bf16 operands (mlb_gemm_bf16,
// sdpa_forward_bf16, sdpa_backward_bf16: AVX-512 BF16, fp32 sums; fp32 on a CPU without it); the
// norms and the rest stay fp32. The CUDA table calls cuda_ops.h (in a build without the CUDA part each of its ops
// fails with "built without CUDA", so callers need no #ifdef); its GEMMs (linear, conv, attention)
// run at be->precision. Ops are asynchronous on the device: download synchronises.
// The ops are listed once, with their contracts, in backend_ops.def; the fields below, the tables
// and the CUDA declarations and stubs are generated from that list (docs/cuda.md "Adding an op").
#ifndef MATLABER_BACKEND_H
#define MATLABER_BACKEND_H
#include <stddef.h>
#include "matlaber/conv_ops.h"
#include "matlaber/cuda_ops.h"
#include "matlaber/device.h"
#include "matlaber/envmap.h"
#include "matlaber/error.h"
#include "matlaber/hashgrid.h"
#include "matlaber/nn.h"
#include "matlaber/shade.h"

typedef struct mlb_backend mlb_backend;
struct mlb_backend {
    mlb_device device;
    mlb_gemm_precision precision;   // the GEMMs' operands: CUDA any; the CPU fp32, or bf16 (linear, conv)
    // the ops, in the order of backend_ops.def (which documents each)
#define MLB_OP(name, cuda_fn, params) mlb_status (*name) params;
#define MLB_GEMM_OP(name, cuda_fn, params, args) mlb_status (*name)(const mlb_backend* be, MLB_ARGS params);
#define MLB_DEVICE_OP(ret, name, params) ret (*name) params;
#include "matlaber/backend_ops.def"
};

// The table of device d (CUDA ops at GEMM precision prec; the CPU's bf16 table for MLB_GEMM_BF16,
// its fp32 one for any other prec: fp16 and tf32 are GPU formats). Never NULL; the CUDA table's ops
// fail cleanly when the build or the machine has no GPU.
const mlb_backend* mlb_backend_for(mlb_device d, mlb_gemm_precision prec);
const mlb_backend* mlb_backend_cpu(void);
// The CPU's bf16 table for models whose linear and conv weights are stored in bf16 (uint16_t values
// behind the weight pointers; mlb_unet_options.bf16_weights): the bf16 table's results bit for bit,
// at half the weights' memory; the backward of linear and conv fails (MLB_ERR_UNSUPPORTED).
const mlb_backend* mlb_backend_cpu_bf16_stored(void);
// The CPU's fp32 table for a model whose linear and conv weights are IEEE half in memory (uint16_t
// behind the weight pointers; mlb_unet_options.f16_weights), widened per call: the fp32 table's
// results bit for bit. No backward through those weights.
const mlb_backend* mlb_backend_cpu_f16_stored(void);

#endif
