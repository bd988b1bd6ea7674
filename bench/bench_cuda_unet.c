// The SD 1.5 UNet forward on the GPU: a full-size UNet (859.5 M parameters, random
// weights: the time does not depend on them) at a 64^2 latent (512^2 images), context 77 x 768,
// batch 2 (one CFG step) and 18 (9 views x CFG), at each GEMM precision. Median of `reps` forwards
// after 2 warm-ups, device events. Then one profiled forward per batch (bf16): every op timed on
// its own (synchronised) and its FLOPs counted, against the GEMM rate bench_cuda measures.
// Usage: bench_cuda_unet [reps] (default 5). Exits 0 with a message without a GPU. docs/cuda.md.
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/backend.h"
#include "matlaber/unet.h"
#include "matlaber/unet_random.h"
#include "unet_profile.h"

#define TRY(x) do { if ((x) != MLB_OK) { fprintf(stderr, "bench_cuda_unet: %s\n", mlb_last_error()); exit(1); } } while (0)

static int cmp_double(const void* a, const void* b) {
    double x = *(const double*)a, y = *(const double*)b;
    return x < y ? -1 : x > y;
}

// ---- the profile (unet_profile.h), each op timed with device events around it ----
static const char* p_names[P_COUNT] = {"conv2d", "linear (GEMM)", "attention",
                                       "group/layer norm", "glue (add, transpose, GEGLU, copies)"};

static void profile(const mlb_unet* u, float* out, const float* x, const float* t, const float* ctx, int N, int H, int W,
                    mlb_gemm_precision prec, double total_ms) {
    prof_begin = mlb_cuda_timer_begin;
    prof_end = mlb_cuda_timer_end;
    TRY(unet_profile_run(mlb_backend_for(MLB_DEVICE_CUDA, prec), u, out, x, t, ctx, N, H, W));
    printf("\nprofile, batch %d, %s (each op synchronised; un-profiled forward %.2f ms; activations %.2f GiB):\n", N,
           mlb_gemm_precision_name(prec), total_ms, p_arena * 4.0 / 1073741824.0);
    char conv[64];
    snprintf(conv, sizeof conv, "%s (%s)", p_names[0], profile_conv_path());
    const char* names[P_COUNT] = {conv, p_names[1], p_names[2], p_names[3], p_names[4]};
    profile_print(names);
}

int main(int argc, char** argv) {
    int reps = argc > 1 ? atoi(argv[1]) : 5;
    if (reps < 1 || reps > 100) reps = 5;
    int n_gpu = 0;
    if (mlb_cuda_probe(&n_gpu) != MLB_OK || mlb_cuda_init(0) != MLB_OK) {
        printf("bench_cuda_unet: no CUDA device, nothing to measure (%s)\n", mlb_last_error());
        return 0;
    }
    char desc[256];
    TRY(mlb_cuda_describe(0, desc, sizeof desc));
    mlb_unet_config cfg = mlb_unet_sd15_config();
    mlb_unet* u;
    TRY(mlb_unet_create(&cfg, MLB_DEVICE_CUDA, &u));
    // weights uniform in [-0.02, 0.02] (norm weights included): finite activations, the real sizes
    TRY(mlb_cuda_fill_uniform(u->params, u->n_params, 7, -0.02f, 0.02f));
    printf("bench_cuda_unet: %s; SD 1.5 UNet, %.1f M parameters (fp32 on the device), latent 64x64, context 77x768; "
           "median of %d after 2 warm-ups\n\n", desc, u->n_params / 1e6, reps);
    printf("%-6s %-6s %10s %10s %14s\n", "batch", "prec", "ms", "img/s", "held GiB");
    const int H = 64, W = 64, Tc = 77, batches[2] = {2, 18};
    for (int bi = 0; bi < 2; bi++) {
        int N = batches[bi];
        size_t nx = (size_t)N * 4 * H * W, nc = (size_t)N * Tc * 768;
        float *x, *ctx, *out, t[18];
        for (int i = 0; i < N; i++) t[i] = 20.0f + 50.0f * i;
        TRY(mlb_cuda_malloc((void**)&x, nx * 4));
        TRY(mlb_cuda_malloc((void**)&ctx, nc * 4));
        TRY(mlb_cuda_malloc((void**)&out, nx * 4));
        TRY(mlb_cuda_fill_uniform(x, nx, 1, -1, 1));
        TRY(mlb_cuda_fill_uniform(ctx, nc, 2, -1, 1));
        double bf16_ms = 0;
        for (int p = 0; p < 4; p++) {
            const mlb_backend* be = mlb_backend_for(MLB_DEVICE_CUDA, (mlb_gemm_precision)p);
            double ms[100];
            for (int i = 0; i < 2; i++) TRY(mlb_unet_forward(be, u, out, x, t, ctx, N, H, W, Tc, NULL, NULL));
            TRY(mlb_cuda_sync());
            for (int i = 0; i < reps; i++) {
                TRY(mlb_cuda_timer_begin());
                TRY(mlb_unet_forward(be, u, out, x, t, ctx, N, H, W, Tc, NULL, NULL));
                TRY(mlb_cuda_timer_end(&ms[i]));
            }
            qsort(ms, reps, sizeof ms[0], cmp_double);
            size_t fr, tot;
            TRY(mlb_cuda_mem_info(&fr, &tot));
            float probe[4];
            TRY(be->download(probe, out, 4));
            for (int i = 0; i < 4; i++)
                if (!isfinite(probe[i])) { fprintf(stderr, "bench_cuda_unet: non-finite output\n"); return 1; }
            printf("%-6d %-6s %10.2f %10.1f %14.1f\n", N, mlb_gemm_precision_name((mlb_gemm_precision)p), ms[reps / 2],
                   N * 1000.0 / ms[reps / 2], (tot - fr) / 1073741824.0);
            fflush(stdout);
            if (p == MLB_GEMM_BF16) bf16_ms = ms[reps / 2];
        }
        profile(u, out, x, t, ctx, N, H, W, MLB_GEMM_BF16, bf16_ms);
        printf("\n");
        mlb_cuda_free(x); mlb_cuda_free(ctx); mlb_cuda_free(out);
    }
    mlb_unet_free(u);
    return 0;
}
