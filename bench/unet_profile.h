// The per-op profile of the UNet (bench_cuda_unet.c on the GPU, bench_unet_cpu.c on the CPU) and of
// the VAE's encoder forward and backward (bench_cuda_vae.c): a copy of an op table whose ops time
// themselves with the bench's clock (prof_begin / prof_end, which on the GPU synchronise around
// each op) and count their GEMM FLOPs (backwards: one GEMM's worth per gradient asked for; the
// attention backward five), so one pass through it says where the time goes. Not a test: numbers only.
#ifndef MATLABER_UNET_PROFILE_H
#define MATLABER_UNET_PROFILE_H
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/backend.h"
#include "matlaber/cuda_ops.h"
#include "matlaber/progress.h"
#include "matlaber/unet.h"

enum { P_CONV, P_LINEAR, P_SDPA, P_NORM, P_GLUE, P_COUNT };
static double p_ms[P_COUNT], p_flop[P_COUNT];
static long p_calls[P_COUNT];
static size_t p_arena;   // the largest allocation: the activation arena
static const mlb_backend* inner;
static mlb_status (*prof_begin)(void);
static mlb_status (*prof_end)(double* ms);

// The CPU's clock for prof_begin / prof_end (its ops return when done).
static double profile_wall_t0;
static inline mlb_status profile_wall_begin(void) { profile_wall_t0 = mlb_now_seconds(); return MLB_OK; }
static inline mlb_status profile_wall_end(double* ms) { *ms = 1e3 * (mlb_now_seconds() - profile_wall_t0); return MLB_OK; }

#define PROF(cat, flop, call) do { double ms_; MLB_TRY(prof_begin()); MLB_TRY(call); MLB_TRY(prof_end(&ms_)); \
    p_ms[cat] += ms_; p_flop[cat] += (flop); p_calls[cat]++; return MLB_OK; } while (0)

static mlb_status w_alloc(float** out, size_t n) {
    if (n > p_arena) p_arena = n;
    return inner->alloc(out, n);
}
static mlb_status w_linear(const mlb_backend* be, float* o, const float* i, const float* w, const float* b, int B, int C,
                           int OC) {
    (void)be;
    PROF(P_LINEAR, 2.0 * B * C * OC, inner->linear(inner, o, i, w, b, B, C, OC));
}
static mlb_status w_conv(const mlb_backend* be, float* o, const float* i, const float* w, const float* b,
                         const mlb_conv2d* cv) {
    (void)be;
    double f = 2.0 * cv->N * cv->OC * mlb_conv2d_out_h(cv) * mlb_conv2d_out_w(cv) * cv->C * cv->KH * cv->KW;
    PROF(P_CONV, f, inner->conv2d(inner, o, i, w, b, cv));
}
static mlb_status w_sdpa(const mlb_backend* be, float* o, float* lse, const float* q, const float* k, const float* v,
                         int B, int Tq, int Tk, int C, int NH, int ldq, int ldkv) {
    (void)be;
    PROF(P_SDPA, 4.0 * B * Tq * Tk * C, inner->sdpa(inner, o, lse, q, k, v, B, Tq, Tk, C, NH, ldq, ldkv));
}
static mlb_status w_gn(float* o, float* mean, float* rstd, const float* i, const float* w, const float* b, int N, int C,
                       int HW, int G, float eps, mlb_activation a) {
    PROF(P_NORM, 0, inner->groupnorm(o, mean, rstd, i, w, b, N, C, HW, G, eps, a));
}
static mlb_status w_ln(float* o, const float* i, const float* w, const float* b, int N, int C, float eps) {
    PROF(P_NORM, 0, inner->layernorm(o, i, w, b, N, C, eps));
}
static mlb_status w_act(float* o, const float* i, size_t n, mlb_activation a) { PROF(P_GLUE, 0, inner->activation(o, i, n, a)); }
static mlb_status w_add(float* y, const float* x, size_t n) { PROF(P_GLUE, 0, inner->add(y, x, n)); }
static mlb_status w_addc(float* x, const float* v, int N, int C, int HW) { PROF(P_GLUE, 0, inner->add_channel(x, v, N, C, HW)); }
static mlb_status w_tr(float* o, const float* i, int N, int R, int S, int acc) {
    PROF(P_GLUE, 0, inner->transpose_last2(o, i, N, R, S, acc));
}
static mlb_status w_geglu(float* o, const float* i, int rows, int C4) { PROF(P_GLUE, 0, inner->geglu(o, i, rows, C4)); }
static mlb_status w_up(float* o, const float* i, int N, int C, int H, int W) {
    PROF(P_GLUE, 0, inner->upsample_nearest2x(o, i, N, C, H, W));
}
static mlb_status w_rows(float* d, size_t dp, const float* s, size_t sp, size_t w, size_t r) {
    PROF(P_GLUE, 0, inner->copy_rows(d, dp, s, sp, w, r));
}

static mlb_status w_conv_bwd(const mlb_backend* be, float* din, float* dw, float* db, const float* dout,
                             const float* in, const float* w, const mlb_conv2d* cv) {
    (void)be;
    double f = 2.0 * cv->N * cv->OC * mlb_conv2d_out_h(cv) * mlb_conv2d_out_w(cv) * cv->C * cv->KH * cv->KW;
    PROF(P_CONV, f * ((din != NULL) + (dw != NULL)), inner->conv2d_backward(inner, din, dw, db, dout, in, w, cv));
}
static mlb_status w_gn_bwd(float* din, float* dw, float* db, const float* dout, const float* in, const float* w,
                           const float* b, const float* mean, const float* rstd, int N, int C, int HW, int G,
                           mlb_activation a) {
    PROF(P_NORM, 0, inner->groupnorm_backward(din, dw, db, dout, in, w, b, mean, rstd, N, C, HW, G, a));
}
static mlb_status w_sdpa_bwd(const mlb_backend* be, float* dq, float* dk, float* dv, const float* dout, const float* out,
                             const float* lse, const float* q, const float* k, const float* v, int B, int Tq, int Tk,
                             int C, int NH, int ldq, int ldkv) {
    (void)be;
    PROF(P_SDPA, 10.0 * B * Tq * Tk * C,
         inner->sdpa_backward(inner, dq, dk, dv, dout, out, lse, q, k, v, B, Tq, Tk, C, NH, ldq, ldkv));
}
static mlb_status w_act_bwd(float* din, const float* dout, const float* in, size_t n, mlb_activation a) {
    PROF(P_GLUE, 0, inner->activation_backward(din, dout, in, n, a));
}

// *w = the profiling copy of be (its ops call be's), the counters reset.
static void profile_wrap(const mlb_backend* be, mlb_backend* w) {
    inner = be;
    *w = *be;
    w->linear = w_linear; w->conv2d = w_conv; w->sdpa = w_sdpa; w->groupnorm = w_gn; w->layernorm = w_ln;
    w->activation = w_act; w->add = w_add; w->add_channel = w_addc; w->transpose_last2 = w_tr; w->geglu = w_geglu;
    w->upsample_nearest2x = w_up; w->copy_rows = w_rows; w->alloc = w_alloc;
    w->conv2d_backward = w_conv_bwd; w->groupnorm_backward = w_gn_bwd; w->sdpa_backward = w_sdpa_bwd;
    w->activation_backward = w_act_bwd;
    p_arena = 0;
    memset(p_ms, 0, sizeof p_ms); memset(p_flop, 0, sizeof p_flop); memset(p_calls, 0, sizeof p_calls);
}

// The convolutions' path as the profile names it: cuDNN (symmetric padding) unless MLB_CUDNN=0 or
// the build has none.
static inline const char* profile_conv_path(void) {
    const char* off = getenv("MLB_CUDNN");
    return mlb_cuda_cudnn_version() && !(off && off[0] == '0') ? "cuDNN" : "im2col + GEMM";
}

// The table of the counters, one row per category (names[P_COUNT]), as milliseconds.
static inline void profile_print(const char* const* names) {
    double sum = 0, flop = 0;
    for (int c = 0; c < P_COUNT; c++) { sum += p_ms[c]; flop += p_flop[c]; }
    printf("%-38s %7s %10s %7s %10s %10s\n", "op", "calls", "ms", "share", "GFLOP", "TFLOP/s");
    for (int c = 0; c < P_COUNT; c++)
        printf("%-38s %7ld %10.2f %6.1f%% %10.1f %10.1f\n", names[c], p_calls[c], p_ms[c], 100 * p_ms[c] / sum,
               p_flop[c] / 1e9, p_ms[c] > 0 && p_flop[c] > 0 ? p_flop[c] / (p_ms[c] * 1e9) : 0.0);
    printf("%-38s %7s %10.2f %6.1f%% %10.1f %10.1f\n", "total", "", sum, 100.0, flop / 1e9, flop / (sum * 1e9));
}

// One forward of u through the profiling copy of `be`, the counters reset first.
static inline mlb_status unet_profile_run(const mlb_backend* be, const mlb_unet* u, float* out, const float* x,
                                          const float* t, const float* ctx, int N, int H, int W) {
    mlb_backend w;
    profile_wrap(be, &w);
    return mlb_unet_forward(&w, u, out, x, t, ctx, N, H, W, 77, NULL, NULL);
}

#endif
