// The op tables of backend.h: the CPU's over host memory (fp32, and bf16 for the linear and conv
// GEMMs) and CUDA's over device memory, one per GEMM precision.
#include "matlaber/backend.h"
#include "matlaber/half.h"
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/image_convert.h"
#include "matlaber/rng.h"
#include "matlaber/raster.h"
#include "matlaber/transformer_ops.h"
#include "nn/simd_rows.h"

// ---- CPU -----------------------------------------------------------------------------------------
// The ops both CPU tables share, written once over `real` (float here)
#include "nn/backend_host.h"

// The float table's own: ops with no double twin, or a float-only path (SIMD rows, bf16 GEMMs,
// weights stored in bf16 or f16)
static mlb_status cpu_embedding(float* out, const int32_t* tokens, const float* wte, const float* wpe, int B, int T,
                               int C, int V) {
    return embedding_forward(out, (const int*)tokens, wte, wpe, B, T, C, V);
}
// (GCC's -O2 leaves the plain loop scalar: y may alias x. 2-3% of a tiny generation.)
static mlb_status cpu_add(float* y, const float* x, size_t n) {
    const mlb_simd_level lv = mlb_simd_kernels();
    if (lv != MLB_SIMD_SCALAR) mlb_add_row(lv, y, x, n);
    else
        for (size_t i = 0; i < n; i++) y[i] += x[i];
    return MLB_OK;
}
// in [rows, 2 C4] = [a | gate] per row; out [rows, C4] = a · GELU(gate). In SIMD lanes where the CPU
// has them (simd_rows.h: libm's erfcf was 3% of a tiny generation), else through mlb_act.
static mlb_status cpu_geglu(float* out, const float* in, int rows, int C4) {
    const mlb_simd_level lv = mlb_simd_kernels();
#pragma omp parallel for schedule(static)
    for (int t = 0; t < rows; t++) {
        const float* row = in + (size_t)t * 2 * C4;
        float* g = out + (size_t)t * C4;
        if (lv != MLB_SIMD_SCALAR) mlb_geglu_row(lv, g, row, row + C4, C4);
        else
            for (int j = 0; j < C4; j++) g[j] = row[j] * mlb_act(MLB_ACT_GELU, row[C4 + j]);
    }
    return MLB_OK;
}
static mlb_status cpu_geglu_backward(float* din, const float* dout, const float* in, int rows, int C4) {
    const mlb_simd_level lv = mlb_simd_kernels();
#pragma omp parallel for schedule(static)
    for (int t = 0; t < rows; t++) {
        const float* row = in + (size_t)t * 2 * C4;
        const float* d = dout + (size_t)t * C4;
        float* g = din + (size_t)t * 2 * C4;
        if (lv != MLB_SIMD_SCALAR) {
            mlb_geglu_backward_row(lv, g, g + C4, d, row, row + C4, C4);
            continue;
        }
        for (int j = 0; j < C4; j++) {
            float gate = row[C4 + j];
            g[j] += d[j] * mlb_act(MLB_ACT_GELU, gate);
            g[C4 + j] += d[j] * row[j] * mlb_act_d1(MLB_ACT_GELU, gate);
        }
    }
    return MLB_OK;
}
static mlb_status cpu_add_channel_backward(float* dv, const float* dx, int N, int C, int HW) {
#pragma omp parallel for schedule(static)
    for (long r = 0; r < (long)N * C; r++) {
        const float* p = dx + (size_t)r * HW;
        double s = 0;
        for (int i = 0; i < HW; i++) s += p[i];
        dv[r] += (float)s;
    }
    return MLB_OK;
}

static mlb_status cpu_hashgrid(const mlb_hashgrid* g, const float* params, float* out, const float* x, int N) {
    mlb_hashgrid h = *g;
    h.params = (float*)params;   // read only: the forward does not write the table
    hashgrid_forward(&h, out, x, N);
    return MLB_OK;
}
static mlb_status cpu_hashgrid_backward(const mlb_hashgrid* g, const float* params, float* dparams, float* dx,
                                        const float* dout, const float* x, int N) {
    mlb_hashgrid h = *g;
    h.params = (float*)params;
    hashgrid_backward(&h, dparams, dx, dout, x, N);
    return MLB_OK;
}
static mlb_status cpu_adam(float* params, const float* grads, float* m, float* v, size_t n, const mlb_adam_config* cfg,
                           long t) {
    adam_update(params, grads, m, v, n, cfg, t);
    return MLB_OK;
}

// bf16: the linear and conv GEMMs and the attention with bf16 operands (mlb_gemm_bf16 and the ops
// built on its kernel), all else as the fp32 table.
static mlb_status cpu_linear_bf16(const mlb_backend* be, float* out, const float* in, const float* w, const float* b,
                                  int B, int C, int OC) {
    (void)be;
    linear_forward_bf16(out, in, w, b, B, C, OC);
    return MLB_OK;
}
static mlb_status cpu_linear_backward_bf16(const mlb_backend* be, float* din, float* dw, float* db, const float* dout,
                                           const float* in, const float* w, int B, int C, int OC) {
    (void)be;
    linear_backward_bf16(din, dw, db, dout, in, w, B, C, OC);
    return MLB_OK;
}
static mlb_status cpu_conv2d_bf16(const mlb_backend* be, float* out, const float* in, const float* w, const float* b,
                                  const mlb_conv2d* cv) {
    (void)be;
    return conv2d_forward_bf16(out, in, w, b, cv, NULL);
}
static mlb_status cpu_conv2d_backward_bf16(const mlb_backend* be, float* din, float* dw, float* db, const float* dout,
                                           const float* in, const float* w, const mlb_conv2d* cv) {
    (void)be;
    return conv2d_backward_bf16(din, dw, db, dout, in, w, cv, NULL);
}

static mlb_status cpu_sdpa_backward_bf16(const mlb_backend* be, float* dq, float* dk, float* dv, const float* dout,
                                         const float* out, const float* lse, const float* q, const float* k,
                                         const float* v, int B, int Tq, int Tk, int C, int NH, int ldq, int ldkv) {
    (void)be;
    return sdpa_backward_bf16(dq, dk, dv, dout, out, lse, q, k, v, B, Tq, Tk, C, NH, ldq, ldkv, NULL);
}
static mlb_status cpu_sdpa_bf16(const mlb_backend* be, float* out, float* lse, const float* q, const float* k,
                                const float* v, int B, int Tq, int Tk, int C, int NH, int ldq, int ldkv) {
    (void)be;
    return sdpa_forward_bf16(out, lse, q, k, v, B, Tq, Tk, C, NH, ldq, ldkv);
}

// The bf16 table for a model whose linear and conv weights are packed for the bf16 kernel at load
// (mlb_unet_options bf16_weights): the weight pointers it is given hold those uint32_t words. No
// backward through them.
static mlb_status cpu_linear_bf16_stored(const mlb_backend* be, float* out, const float* in, const float* w,
                                         const float* b, int B, int C, int OC) {
    (void)be;
    return linear_forward_bf16_packed(out, in, (const uint32_t*)w, b, B, C, OC);
}
static mlb_status cpu_conv2d_bf16_stored(const mlb_backend* be, float* out, const float* in, const float* w,
                                         const float* b, const mlb_conv2d* cv) {
    (void)be;
    return conv2d_forward_bf16_packed(out, in, (const uint32_t*)w, b, cv);
}
static mlb_status no_backward_stored(void) {
    return mlb_fail(MLB_ERR_UNSUPPORTED, "no backward through weights stored in bf16 or f16 (load the model with fp32 weights)");
}
static mlb_status cpu_linear_backward_bf16_stored(const mlb_backend* be, float* din, float* dw, float* db,
                                                  const float* dout, const float* in, const float* w, int B, int C,
                                                  int OC) {
    (void)be; (void)din; (void)dw; (void)db; (void)dout; (void)in; (void)w; (void)B; (void)C; (void)OC;
    return no_backward_stored();
}
static mlb_status cpu_conv2d_backward_bf16_stored(const mlb_backend* be, float* din, float* dw, float* db,
                                                  const float* dout, const float* in, const float* w,
                                                  const mlb_conv2d* cv) {
    (void)be; (void)din; (void)dw; (void)db; (void)dout; (void)in; (void)w; (void)cv;
    return no_backward_stored();
}

// The fp32 table for a model whose linear and conv weights stay IEEE half in memory, as its file
// stores them (mlb_unet_options f16_weights): the weight pointers it is given hold uint16_t values.
// Each call widens its weight to fp32 (exactly, F16C) and runs the fp32 op: the fp32 table's bits
// with half the weights' memory (SD 1.5's UNet 1.7 instead of 3.4 GB on CPUs without AVX-512 BF16).
// The widened weight goes to one buffer per calling thread, grown to the largest weight and kept:
// a fresh allocation per call would page-fault every weight's 4 bytes in again on every forward.
static _Thread_local float* widened_buf;
static _Thread_local size_t widened_cap;
static mlb_status widened(float** out, const float* w, size_t n) {
    if (n > widened_cap) {
        float* p = realloc(widened_buf, n * sizeof(float));
        if (!p) return mlb_fail(MLB_ERR_NOMEM, "out of memory widening a %zu-value f16 weight", n);
        widened_buf = p;
        widened_cap = n;
    }
    mlb_f16_to_f32_array(widened_buf, w, n);
    *out = widened_buf;
    return MLB_OK;
}
static mlb_status cpu_linear_f16_stored(const mlb_backend* be, float* out, const float* in, const float* w,
                                        const float* b, int B, int C, int OC) {
    float* w32;
    MLB_TRY(widened(&w32, w, (size_t)OC * C));
    return cpu_linear(be, out, in, w32, b, B, C, OC);
}
static mlb_status cpu_conv2d_f16_stored(const mlb_backend* be, float* out, const float* in, const float* w,
                                        const float* b, const mlb_conv2d* cv) {
    MLB_TRY(mlb_conv2d_check(cv));
    float* w32;
    MLB_TRY(widened(&w32, w, (size_t)cv->OC * cv->C * cv->KH * cv->KW));
    return cpu_conv2d(be, out, in, w32, b, cv);
}
#define cpu_linear_backward_f16_stored cpu_linear_backward_bf16_stored
#define cpu_conv2d_backward_f16_stored cpu_conv2d_backward_bf16_stored
#define cpu_sdpa_f16_stored cpu_sdpa
#define cpu_sdpa_backward_f16_stored cpu_sdpa_backward

// The guidance's conversions between renders and the diffusion model's images (image_convert.h)
static mlb_status check_resize(const char* fn, int n, int H, int W, int C, int h, int w) {
    if (n < 0 || H < 1 || W < 1 || C < 1 || h < 1 || w < 1)
        return mlb_fail(MLB_ERR_ARG, "%s: %d images of %dx%d x %d to %dx%d", fn, n, W, H, C, w, h);
    return MLB_OK;
}
static mlb_status cpu_area_resize(float* dst, const float* src, int n, int H, int W, int C, int h, int w) {
    MLB_TRY(check_resize("area_resize", n, H, W, C, h, w));
    mlb_area_resize_nhwc_to_nchw(dst, src, n, H, W, C, h, w);
    return MLB_OK;
}
static mlb_status cpu_area_resize_backward(float* dsrc, const float* ddst, int n, int H, int W, int C, int h, int w) {
    MLB_TRY(check_resize("area_resize_backward", n, H, W, C, h, w));
    if (dsrc) mlb_area_resize_nhwc_to_nchw_backward(dsrc, ddst, n, H, W, C, h, w);
    return MLB_OK;
}
static mlb_status cpu_renders_to_sd(float* x, const float* renders, int n, int H, int W, int normal) {
    MLB_TRY(check_resize("renders_to_sd", n, H, W, 4, 1, 1));
    mlb_renders_to_sd(x, renders, n, H, W, normal);
    return MLB_OK;
}
static mlb_status cpu_renders_to_sd_backward(float* drenders, const float* dx, int n, int H, int W, int normal) {
    MLB_TRY(check_resize("renders_to_sd_backward", n, H, W, 4, 1, 1));
    if (drenders) mlb_renders_to_sd_backward(drenders, dx, n, H, W, normal);
    return MLB_OK;
}
static mlb_status cpu_axpby_rows(float* out, const float* x, const float* y, int B, size_t n, const float* a,
                                 const float* c) {
    if (B < 0 || B > MLB_OP_MAX_ROWS) return mlb_fail(MLB_ERR_ARG, "axpby_rows: %d rows (0..%d)", B, MLB_OP_MAX_ROWS);
    for (int b = 0; b < B; b++)
        for (size_t i = 0; i < n; i++) {
            size_t k = (size_t)b * n + i;
            out[k] = a[b] * x[k] + c[b] * y[k];
        }
    return MLB_OK;
}
static mlb_status cpu_fill_normal(float* out, size_t n, uint64_t seed, uint64_t stream, uint64_t offset) {
    mlb_rng_fill_normal(out, n, seed, stream, offset, 0.0f, 1.0f);
    return MLB_OK;
}
static mlb_status cpu_sds_grad(float* eps, float* grad, float* dz, float* sumsq, const float* noise, int B, size_t n,
                               float scale, const float* w, float div, float mul) {
    if (B < 0 || B > MLB_OP_MAX_ROWS) return mlb_fail(MLB_ERR_ARG, "sds_grad: %d rows (0..%d)", B, MLB_OP_MAX_ROWS);
    const size_t nall = (size_t)B * n;
    for (size_t i = 0; i < nall; i++) {
        float u = eps[nall + i];
        eps[i] = u + scale * (eps[i] - u);
    }
    double l = 0;
    for (int b = 0; b < B; b++)
        for (size_t i = 0; i < n; i++) {
            size_t k = (size_t)b * n + i;
            float g = w[b] * (eps[k] - noise[k]);
            if (!isfinite(g)) g = 0.0f;
            if (grad) grad[k] = g;
            if (dz) dz[k] = g / div * mul;
            l += (double)g * g;
        }
    mlb_sumsq_split(l, sumsq);
    return MLB_OK;
}
static mlb_status cpu_affine_columns(float* y, const float* x, size_t n, int C, const double* scale,
                                     const double* shift, int in_float) {
    if (C < 1 || C > 8) return mlb_fail(MLB_ERR_ARG, "affine_columns: %d columns (1..8)", C);
    if (in_float) {
        float a[8], b[8];
        for (int c = 0; c < C; c++) a[c] = (float)scale[c], b[c] = shift ? (float)shift[c] : 0;
        for (size_t i = 0; i < n; i++)
            for (int c = 0; c < C; c++) y[i * C + c] = shift ? x[i * C + c] * a[c] + b[c] : x[i * C + c] * a[c];
        return MLB_OK;
    }
    for (size_t i = 0; i < n; i++)
        for (int c = 0; c < C; c++)
            y[i * C + c] = (float)(shift ? shift[c] + scale[c] * (double)x[i * C + c] : scale[c] * (double)x[i * C + c]);
    return MLB_OK;
}

// The stored-weights table's attention is the bf16 table's (no weights in it).
#define cpu_sdpa_bf16_stored cpu_sdpa_bf16
#define cpu_sdpa_backward_bf16_stored cpu_sdpa_backward_bf16

// The CPU's tables differ only in their precision and their GEMM ops (cpu_<op>, cpu_<op>_bf16,
// cpu_<op>_bf16_stored, cpu_<op>_f16_stored); every other op is cpu_<op> (nn/backend_entries.h).
static const mlb_backend cpu_table = {.device = MLB_DEVICE_CPU, .precision = MLB_GEMM_FP32,
#define CPU_GEMM(op) cpu_##op
#include "nn/backend_entries.h"
};
static const mlb_backend cpu_bf16_table = {.device = MLB_DEVICE_CPU, .precision = MLB_GEMM_BF16,
#define CPU_GEMM(op) cpu_##op##_bf16
#include "nn/backend_entries.h"
};
static const mlb_backend cpu_bf16_stored_table = {.device = MLB_DEVICE_CPU, .precision = MLB_GEMM_BF16,
#define CPU_GEMM(op) cpu_##op##_bf16_stored
#include "nn/backend_entries.h"
};
static const mlb_backend cpu_f16_stored_table = {.device = MLB_DEVICE_CPU, .precision = MLB_GEMM_FP32,
#define CPU_GEMM(op) cpu_##op##_f16_stored
#include "nn/backend_entries.h"
};

// ---- CUDA ----------------------------------------------------------------------------------------
static mlb_status cuda_alloc(float** out, size_t n) {
    void* p = NULL;
    mlb_status s = mlb_cuda_malloc(&p, (n ? n : 1) * sizeof(float));
    *out = p;
    return s;
}
static void cuda_release(void* p) { mlb_cuda_free(p); }
static mlb_status cuda_upload(float* dst, const float* host, size_t n) {
    return mlb_cuda_copy_to_device(dst, host, n * sizeof(float));
}
static mlb_status cuda_download(float* host, const float* src, size_t n) {
    MLB_TRY(mlb_cuda_sync());
    return mlb_cuda_copy_to_host(host, src, n * sizeof(float));
}
static mlb_status cuda_zero(float* p, size_t n) { return mlb_cuda_memset(p, 0, n * sizeof(float)); }
static mlb_status cuda_copy(float* dst, const float* src, size_t n) { return mlb_cuda_copy_d2d(dst, src, n * sizeof(float)); }

static mlb_status cuda_layernorm(float* out, const float* in, const float* w, const float* b, int N, int C, float eps) {
    return mlb_cuda_layernorm_forward(out, NULL, NULL, in, w, b, N, C, eps);
}

static mlb_status cuda_light_upload(void** handle, const mlb_envlight* light) {
    mlb_cuda_envlight* l = calloc(1, sizeof *l);
    if (!l) return mlb_fail(MLB_ERR_NOMEM, "out of memory");
    mlb_status s = mlb_cuda_envlight_upload(l, light);
    if (s) { free(l); return s; }
    *handle = l;
    return MLB_OK;
}
static void cuda_light_free(void* handle) {
    if (!handle) return;
    mlb_cuda_envlight_free(handle);
    free(handle);
}
// The uploaded light turned by `rotation`: cos and sin computed as the upload computes them.
static mlb_cuda_envlight cuda_turned(const void* handle, float rotation) {
    mlb_cuda_envlight l = *(const mlb_cuda_envlight*)handle;
    l.rot_cos = (float)cos((double)rotation);
    l.rot_sin = (float)sin((double)rotation);
    return l;
}
static mlb_status cuda_shade(float* out, const float* kd, const float* ks, const float* kr, const float* n,
                             const float* v, int N, const void* handle, float rotation, mlb_fresnel fresnel) {
    mlb_cuda_envlight l = cuda_turned(handle, rotation);
    return mlb_cuda_shade_forward(out, kd, ks, kr, n, v, N, &l, fresnel);
}
static mlb_status cuda_shade_backward(float* dkd, float* dks, float* dkr, float* dn, float* dv, const float* dout,
                                      const float* kd, const float* ks, const float* kr, const float* n, const float* v,
                                      int N, const void* handle, float rotation, mlb_fresnel fresnel) {
    mlb_cuda_envlight l = cuda_turned(handle, rotation);
    return mlb_cuda_shade_backward(dkd, dks, dkr, dn, dv, dout, kd, ks, kr, n, v, N, &l, fresnel);
}

// The GEMM ops at the table's precision: cuda_<op>(be, params) calls cuda_fn(args, be->precision).
#define MLB_GEMM_OP(name, cuda_fn, params, args) \
    static mlb_status cuda_##name(const mlb_backend* be, MLB_ARGS params) { return cuda_fn(MLB_ARGS args, be->precision); }
#include "matlaber/backend_ops.def"

// One table per GEMM precision, indexed by it, alike but for .precision: an op of the list calls its
// CUDA function, a GEMM op the wrapper above, a memory or light op the hand-written cuda_<op>
// (nn/backend_entries.h).
#define TABLE_CUDA
static const mlb_backend cuda_tables[4] = {
    [MLB_GEMM_FP32] = {.device = MLB_DEVICE_CUDA, .precision = MLB_GEMM_FP32,
#include "nn/backend_entries.h"
    },
    [MLB_GEMM_TF32] = {.device = MLB_DEVICE_CUDA, .precision = MLB_GEMM_TF32,
#include "nn/backend_entries.h"
    },
    [MLB_GEMM_FP16] = {.device = MLB_DEVICE_CUDA, .precision = MLB_GEMM_FP16,
#include "nn/backend_entries.h"
    },
    [MLB_GEMM_BF16] = {.device = MLB_DEVICE_CUDA, .precision = MLB_GEMM_BF16,
#include "nn/backend_entries.h"
    },
};
#undef TABLE_CUDA

const mlb_backend* mlb_backend_cpu(void) { return &cpu_table; }
const mlb_backend* mlb_backend_cpu_bf16_stored(void) { return &cpu_bf16_stored_table; }
const mlb_backend* mlb_backend_cpu_f16_stored(void) { return &cpu_f16_stored_table; }

const mlb_backend* mlb_backend_for(mlb_device d, mlb_gemm_precision prec) {
    if (d != MLB_DEVICE_CUDA) return prec == MLB_GEMM_BF16 ? &cpu_bf16_table : &cpu_table;
    return &cuda_tables[prec >= MLB_GEMM_FP32 && prec <= MLB_GEMM_BF16 ? prec : MLB_GEMM_FP32];
}
