// The full-size SD 1.5 UNet forward on the CPU (batch 2 = one CFG step, 64² latent, context 77 x 768)
// in fp32 and with bf16 GEMM operands (the CPU's bf16 table, backend.h), each followed by a profile
// of one forward: every op of the table timed and its GEMM FLOPs counted, so the table says where
// the time goes. Weights uniform in [-0.02, 0.02] made in memory (no file: the time does not
// depend on them). Usage: bench_unet_cpu [--reps N] [--batch N] [--latent N] [--model UNET]: with
// --model, that UNet (a file or a diffusers folder, e.g. models/matlaber-tiny/unet) instead of SD 1.5.
// docs/benchmarks.md.
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
#include "unet_profile.h"

#define TRY(x) do { if ((x) != MLB_OK) { fprintf(stderr, "bench_unet_cpu: %s\n", mlb_last_error()); exit(1); } } while (0)

// ---- the profile (unet_profile.h), each op timed by the wall clock ----
static const char* p_names[P_COUNT] = {"conv2d (im2col + GEMM)", "linear (GEMM)", "attention (GEMM + softmax)",
                                       "group/layer norm", "glue (add, transpose, GEGLU, copies)"};

static void profile(const mlb_unet* u, float* out, const float* x, const float* t, const float* ctx, int N, int H,
                    int W, mlb_gemm_precision prec) {
    prof_begin = profile_wall_begin;
    prof_end = profile_wall_end;
    double t0 = mlb_now_seconds();
    TRY(unet_profile_run(mlb_backend_for(MLB_DEVICE_CPU, prec), u, out, x, t, ctx, N, H, W));
    double total = mlb_now_seconds() - t0, sum = 0, flop = 0;
    for (int c = 0; c < P_COUNT; c++) { sum += p_ms[c] / 1e3; flop += p_flop[c]; }
    printf("\nprofile, %s, batch %d (forward %.2f s, of which in the table's ops %.2f s):\n",
           mlb_gemm_precision_name(prec), N, total, sum);
    printf("| op | calls | s | share | GEMM GFLOP | GFLOP/s |\n|---|--:|--:|--:|--:|--:|\n");
    for (int c = 0; c < P_COUNT; c++)
        printf("| %s | %ld | %.2f | %.1f%% | %.0f | %.1f |\n", p_names[c], p_calls[c], p_ms[c] / 1e3,
               100 * p_ms[c] / 1e3 / sum, p_flop[c] / 1e9, p_ms[c] > 0 && p_flop[c] > 0 ? p_flop[c] / (p_ms[c] * 1e6) : 0.0);
}

int main(int argc, char** argv) {
    mlb_runtime_restart(argv);   // the program's runtime settings (threads.h)
    int reps = 1, N = 2, L = 64;
    const char* model = NULL;
    for (int i = 1; i < argc; i++) {
        if (i + 1 < argc && !strcmp(argv[i], "--reps")) reps = atoi(argv[++i]);
        else if (i + 1 < argc && !strcmp(argv[i], "--batch")) N = atoi(argv[++i]);
        else if (i + 1 < argc && !strcmp(argv[i], "--latent")) L = atoi(argv[++i]);
        else if (i + 1 < argc && !strcmp(argv[i], "--model")) model = argv[++i];
        else { fprintf(stderr, "usage: bench_unet_cpu [--reps 1] [--batch 2] [--latent 64] [--model UNET]\n"); return 2; }
    }
    if (reps < 1) reps = 1;
    if (N < 1) N = 1;
    if (L < 8 || L % 8) L = 64;
    mlb_set_threads(omp_get_max_threads());
    mlb_cpu_info cpu;
    mlb_cpu_detect(&cpu);
    mlb_unet_config cfg = mlb_unet_sd15_config();
    mlb_unet* u;
    if (model) {
        TRY(mlb_unet_load(model, NULL, &u));
        cfg = u->cfg;
    } else {
        TRY(mlb_unet_create(&cfg, MLB_DEVICE_CPU, &u));
        mlb_rng_fill_uniform(u->params, u->n_params, 7, 1, 0, -0.02f, 0.02f);
    }
    printf("bench_unet_cpu: %s, %d threads, OpenBLAS kernels %s, bf16 GEMM %s; %s UNet (%.1f M params), batch %d, "
           "latent %d², context 77 x %d; best of %d\n", cpu.model, omp_get_max_threads(), mlb_blas_corename(),
           mlb_gemm_bf16_native() ? "AVX-512 BF16" : "none (fp32 fallback)", model ? model : "SD 1.5",
           u->n_params / 1e6, N, L, cfg.context_dim, reps);
    if (cfg.in_channels != 4 || cfg.out_channels != 4) { fprintf(stderr, "bench_unet_cpu: not a 4-channel UNet\n"); return 1; }
    size_t nx = (size_t)N * 4 * L * L, nc = (size_t)N * 77 * cfg.context_dim;
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
            TRY(mlb_unet_forward(NULL, u, p ? out : ref, x, t, ctx, N, L, L, 77, NULL, NULL));
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
