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
    // memory: n floats
    mlb_status (*alloc)(float** out, size_t n);
    void (*release)(void* p);
    mlb_status (*upload)(float* dst, const float* host, size_t n);
    mlb_status (*download)(float* host, const float* src, size_t n);
    // rows x width floats, row pitches in floats (a channel concatenation is one such copy per image)
    mlb_status (*copy_rows)(float* dst, size_t dpitch, const float* src, size_t spitch, size_t width, size_t rows);
    mlb_status (*zero)(float* p, size_t n);
    mlb_status (*copy)(float* dst, const float* src, size_t n);   // same device, no overlap
    // ops (the CPU contracts of the same names; backward ops accumulate, any gradient may be NULL)
    mlb_status (*linear)(const mlb_backend* be, float* out, const float* in, const float* w, const float* b, int B,
                         int C, int OC);
    mlb_status (*linear_backward)(const mlb_backend* be, float* din, float* dw, float* db, const float* dout,
                                  const float* in, const float* w, int B, int C, int OC);
    mlb_status (*conv2d)(const mlb_backend* be, float* out, const float* in, const float* w, const float* b,
                         const mlb_conv2d* cv);
    mlb_status (*conv2d_backward)(const mlb_backend* be, float* din, float* dw, float* db, const float* dout,
                                  const float* in, const float* w, const mlb_conv2d* cv);
    // mean/rstd [N, G] may be NULL (not kept)
    mlb_status (*groupnorm)(float* out, float* mean, float* rstd, const float* in, const float* w, const float* b,
                            int N, int C, int HW, int G, float eps, mlb_activation act);
    mlb_status (*groupnorm_backward)(float* din, float* dw, float* db, const float* dout, const float* in,
                                     const float* w, const float* b, const float* mean, const float* rstd, int N,
                                     int C, int HW, int G, mlb_activation act);
    mlb_status (*layernorm)(float* out, const float* in, const float* w, const float* b, int N, int C, float eps);
    mlb_status (*activation)(float* out, const float* in, size_t n, mlb_activation act);
    // lse [B, NH, Tq] may be NULL (not kept)
    mlb_status (*sdpa)(const mlb_backend* be, float* out, float* lse, const float* q, const float* k, const float* v,
                       int B, int Tq, int Tk, int C, int NH, int ldq, int ldkv);
    mlb_status (*sdpa_backward)(const mlb_backend* be, float* dq, float* dk, float* dv, const float* dout,
                                const float* out, const float* lse, const float* q, const float* k, const float* v,
                                int B, int Tq, int Tk, int C, int NH, int ldq, int ldkv);
    mlb_status (*add)(float* y, const float* x, size_t n);                       // y += x
    mlb_status (*add_channel)(float* x, const float* v, int N, int C, int HW);    // x[n,c,:] += v[n,c]
    mlb_status (*transpose_last2)(float* out, const float* in, int N, int R, int S, int accumulate);
    mlb_status (*geglu)(float* out, const float* in, int rows, int C4);           // out[t,j] = in[t,j] gelu(in[t,C4+j])
    mlb_status (*upsample_nearest2x)(float* out, const float* in, int N, int C, int H, int W);
    // ---- the field networks and the renderer's shading (material_net.h, appearance.h) ----
    mlb_status (*activation_backward)(float* din, const float* dout, const float* in, size_t n, mlb_activation act);
    // hash-grid encoding (hashgrid.h): g gives the layout, params the table on this device (g->params
    // is ignored); the backward accumulates into dparams and dx, either may be NULL
    mlb_status (*hashgrid)(const mlb_hashgrid* g, const float* params, float* out, const float* x, int N);
    mlb_status (*hashgrid_backward)(const mlb_hashgrid* g, const float* params, float* dparams, float* dx,
                                    const float* dout, const float* x, int N);
    // AdamW step t (adam_update's contract)
    mlb_status (*adam)(float* params, const float* grads, float* m, float* v, size_t n, const mlb_adam_config* cfg,
                       long t);
    // A pre-integrated light made usable on this device (the CPU keeps a pointer to `light`, which
    // must then outlive the handle; CUDA uploads its cube maps and LUT), and its release.
    mlb_status (*light_upload)(void** handle, const mlb_envlight* light);
    void (*light_free)(void* handle);
    // Split-sum shading (shade.h's contract; backward +=) under the light of `handle` turned by
    // `rotation` radians about +y, as mlb_envlight_set_rotation would turn it.
    mlb_status (*shade)(float* out, const float* kd, const float* ks, const float* kr, const float* n,
                        const float* v, int N, const void* handle, float rotation, mlb_fresnel fresnel);
    mlb_status (*shade_backward)(float* dkd, float* dks, float* dkr, float* dn, float* dv, const float* dout,
                                 const float* kd, const float* ks, const float* kr, const float* n, const float* v,
                                 int N, const void* handle, float rotation, mlb_fresnel fresnel);
    // ---- the UNet's backward (unet_train.h): what its forward keeps and the glue ops' backwards ----
    // layernorm that also writes the statistics mean/rstd [N] (either may be NULL): the same out bits
    mlb_status (*layernorm_stats)(float* out, float* mean, float* rstd, const float* in, const float* w,
                                  const float* b, int N, int C, float eps);
    mlb_status (*layernorm_backward)(float* din, float* dw, float* db, const float* dout, const float* in,
                                     const float* w, const float* mean, const float* rstd, int N, int C);
    // din [rows, 2 C4] += d geglu: din[t,j] += dout[t,j] gelu(g), din[t,C4+j] += dout[t,j] h gelu'(g)
    mlb_status (*geglu_backward)(float* din, const float* dout, const float* in, int rows, int C4);
    // din [N, C, H, W] += the 2x2 block sums of dout [N, C, 2H, 2W]
    mlb_status (*upsample_nearest2x_backward)(float* din, const float* dout, int N, int C, int H, int W);
    // dv[n,c] += sum_i dx[n,c,i] (i < HW; summed in order, in double): add_channel's backward
    mlb_status (*add_channel_backward)(float* dv, const float* dx, int N, int C, int HW);
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

#endif
