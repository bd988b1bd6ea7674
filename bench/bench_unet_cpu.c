// The full-size SD 1.5 UNet forward on the CPU (batch 2 = one CFG step, 64² latent, context 77 x 768)
// in fp32 and with bf16 GEMM operands (the CPU's bf16 table, backend.h), each followed by a profile
// of one forward: every op of the table timed and its GEMM FLOPs counted, so the table says where
// the time goes. Weights uniform in [-0.02, 0.02] made in memory (no file: the time does not
// depend on them). Usage: bench_unet_cpu [--reps N] [--batch N] [--latent N]. docs/benchmarks.md.
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>
#include "bench_util.h"
#include "matlaber/backend.h"
#include "matlaber/cpu.h"
#include "matlaber/threads.h"
#include "matlaber/unet.h"
#include "matlaber/unet_random.h"

#define TRY(x) do { if ((x) != MLB_OK) { fprintf(stderr, "bench_unet_cpu: %s\n", mlb_last_error()); exit(1); } } while (0)

// ---- the profiling table: the inner table's ops, each timed, GEMM FLOPs counted ----
enum { P_CONV, P_LINEAR, P_SDPA, P_NORM, P_GLUE, P_COUNT };
static const char* p_names[P_COUNT] = {"conv2d (im2col + GEMM)", "linear (GEMM)", "attention (GEMM+softmax, fp32)",
                                       "group/layer norm", "glue (add, transpose, GEGLU, copies)"};
static double p_s[P_COUNT], p_flop[P_COUNT];
static long p_calls[P_COUNT];
static const mlb_backend* inner;

#define PROF(cat, flop, call) do { double t0_ = mlb_now_seconds(); MLB_TRY(call); \
    p_s[cat] += mlb_now_seconds() - t0_; p_flop[cat] += (flop); p_calls[cat]++; return MLB_OK; } while (0)

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

static void profile(const mlb_unet* u, float* out, const float* x, const float* t, const float* ctx, int N, int H,
                    int W, mlb_gemm_precision prec) {
    inner = mlb_backend_for(MLB_DEVICE_CPU, prec);
    mlb_backend w = *inner;
    w.linear = w_linear; w.conv2d = w_conv; w.sdpa = w_sdpa; w.groupnorm = w_gn; w.layernorm = w_ln;
    w.activation = w_act; w.add = w_add; w.add_channel = w_addc; w.transpose_last2 = w_tr; w.geglu = w_geglu;
    w.upsample_nearest2x = w_up; w.copy_rows = w_rows;
    memset(p_s, 0, sizeof p_s); memset(p_flop, 0, sizeof p_flop); memset(p_calls, 0, sizeof p_calls);
    double t0 = mlb_now_seconds();
    TRY(mlb_unet_forward_on(&w, u, out, x, t, ctx, N, H, W, 77, NULL, NULL));
    double total = mlb_now_seconds() - t0, sum = 0, flop = 0;
    for (int c = 0; c < P_COUNT; c++) { sum += p_s[c]; flop += p_flop[c]; }
    printf("\nprofile, %s, batch %d (forward %.2f s, of which in the table's ops %.2f s):\n",
           mlb_gemm_precision_name(prec), N, total, sum);
    printf("| op | calls | s | share | GEMM GFLOP | GFLOP/s |\n|---|--:|--:|--:|--:|--:|\n");
    for (int c = 0; c < P_COUNT; c++)
        printf("| %s | %ld | %.2f | %.1f%% | %.0f | %.1f |\n", p_names[c], p_calls[c], p_s[c], 100 * p_s[c] / sum,
               p_flop[c] / 1e9, p_s[c] > 0 && p_flop[c] > 0 ? p_flop[c] / (p_s[c] * 1e9) : 0.0);
}

int main(int argc, char** argv) {
    const char* core = mlb_blas_better_coretype();   // as the program restarts itself (tools/matlaber/main.c)
    int fix_omp = !getenv("OMP_WAIT_POLICY") && !getenv("GOMP_SPINCOUNT");
    if ((core || fix_omp) && !getenv("MATLABER_REEXEC")) {
        if (core) setenv("OPENBLAS_CORETYPE", core, 1);
        if (fix_omp) setenv("OMP_WAIT_POLICY", "passive", 1);
        setenv("MATLABER_REEXEC", "1", 1);
        execv("/proc/self/exe", argv);
    }
    int reps = 1, N = 2, L = 64;
    for (int i = 1; i < argc; i++) {
        if (i + 1 < argc && !strcmp(argv[i], "--reps")) reps = atoi(argv[++i]);
        else if (i + 1 < argc && !strcmp(argv[i], "--batch")) N = atoi(argv[++i]);
        else if (i + 1 < argc && !strcmp(argv[i], "--latent")) L = atoi(argv[++i]);
        else { fprintf(stderr, "usage: bench_unet_cpu [--reps 1] [--batch 2] [--latent 64]\n"); return 2; }
    }
    if (reps < 1) reps = 1;
    if (N < 1) N = 1;
    if (L < 8 || L % 8) L = 64;
    mlb_set_threads(omp_get_max_threads());
    mlb_cpu_info cpu;
    mlb_cpu_detect(&cpu);
    mlb_unet_config cfg = mlb_unet_sd15_config();
    mlb_unet* u;
    TRY(mlb_unet_create(&cfg, MLB_DEVICE_CPU, &u));
    mlb_rng_fill_uniform(u->params, u->n_params, 7, 1, 0, -0.02f, 0.02f);
    printf("bench_unet_cpu: %s, %d threads, OpenBLAS kernels %s, bf16 GEMM %s; SD 1.5 UNet (%.1f M params), batch %d, "
           "latent %d², context 77 x 768; best of %d\n", cpu.model, omp_get_max_threads(), mlb_blas_corename(),
           mlb_gemm_bf16_native() ? "AVX-512 BF16" : "none (fp32 fallback)", u->n_params / 1e6, N, L, reps);
    size_t nx = (size_t)N * 4 * L * L, nc = (size_t)N * 77 * 768;
    float *x = malloc(nx * 4), *ctx = malloc(nc * 4), *out = malloc(nx * 4), *ref = malloc(nx * 4), t[64];
    if (!x || !ctx || !out || !ref || N > 64) return 1;
    mlb_rng_fill_uniform(x, nx, 7, 2, 0, -1, 1);
    mlb_rng_fill_uniform(ctx, nc, 7, 3, 0, -1, 1);
    for (int i = 0; i < N; i++) t[i] = 20.0f + 50.0f * i;
    const mlb_gemm_precision precs[2] = {MLB_GEMM_FP32, MLB_GEMM_BF16};
    double best[2];
    for (int p = 0; p < 2; p++) {
        TRY(mlb_unet_use_device(u, MLB_DEVICE_CPU, precs[p]));
        best[p] = 1e30;
        for (int r = 0; r < reps; r++) {
            double t0 = mlb_now_seconds();
            TRY(mlb_unet_forward(u, p ? out : ref, x, t, ctx, N, L, L, 77, NULL, NULL));
            double dt = mlb_now_seconds() - t0;
            if (dt < best[p]) best[p] = dt;
        }
        printf("%s: %.2f s per forward\n", mlb_gemm_precision_name(precs[p]), best[p]);
        fflush(stdout);
    }
    double d = 0, r = 0;
    for (size_t i = 0; i < nx; i++) d += ((double)out[i] - ref[i]) * (out[i] - ref[i]), r += (double)ref[i] * ref[i];
    printf("bf16 / fp32 time %.2f; ||bf16 - fp32|| / ||fp32|| = %.3g\n", best[1] / best[0], sqrt(d / r));
    for (int p = 0; p < 2; p++) profile(u, out, x, t, ctx, N, L, L, precs[p]);
    mlb_unet_free(u);
    free(x); free(ctx); free(out); free(ref);
    return 0;
}
