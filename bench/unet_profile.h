// The UNet's per-op profile, shared by bench_cuda_unet.c (GPU) and bench_unet_cpu.c (CPU): a copy
// of an op table whose ops time themselves with the bench's clock (prof_begin / prof_end, which on
// the GPU synchronise around each op) and count their GEMM FLOPs, so one forward through it says
// where the time goes. Not a test: numbers only.
#ifndef MATLABER_UNET_PROFILE_H
#define MATLABER_UNET_PROFILE_H
#include <string.h>
#include "matlaber/backend.h"
#include "matlaber/unet.h"

enum { P_CONV, P_LINEAR, P_SDPA, P_NORM, P_GLUE, P_COUNT };
static double p_ms[P_COUNT], p_flop[P_COUNT];
static long p_calls[P_COUNT];
static size_t p_arena;   // the largest allocation: the activation arena
static const mlb_backend* inner;
static mlb_status (*prof_begin)(void);
static mlb_status (*prof_end)(double* ms);

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

// One forward of u through the profiling copy of `be`, the counters reset first.
static mlb_status unet_profile_run(const mlb_backend* be, const mlb_unet* u, float* out, const float* x, const float* t,
                                   const float* ctx, int N, int H, int W) {
    inner = be;
    mlb_backend w = *be;
    w.linear = w_linear; w.conv2d = w_conv; w.sdpa = w_sdpa; w.groupnorm = w_gn; w.layernorm = w_ln;
    w.activation = w_act; w.add = w_add; w.add_channel = w_addc; w.transpose_last2 = w_tr; w.geglu = w_geglu;
    w.upsample_nearest2x = w_up; w.copy_rows = w_rows; w.alloc = w_alloc;
    p_arena = 0;
    memset(p_ms, 0, sizeof p_ms); memset(p_flop, 0, sizeof p_flop); memset(p_calls, 0, sizeof p_calls);
    return mlb_unet_forward_on(&w, u, out, x, t, ctx, N, H, W, 77, NULL, NULL);
}

#endif
