// The SD VAE on the GPU: the full-size SD 1.x VAE (random weights: the time does not
// depend on them) moved with mlb_vae_use_device, timed through its host-buffer API as the SDS
// guidance calls it (the image, the latents and the gradient cross each call; the encoder's cache
// stays on the GPU): encoder forward with the cache + encoder backward for 9 images at 512^2 (one
// RGB-phase SDS step of 9 views), and the decoder for 1 image at 512^2 (txt2img), at fp32, tf32 and
// bf16 GEMMs. Median of `reps` after one warm-up, wall clock (each call ends synchronised).
// Then one profiled encode and backward at bf16 (unet_profile.h: each op on its own, synchronised).
// Usage: bench_cuda_vae [reps] (default 3). Exits 0 with a message without a GPU. docs/cuda.md.
#include <stdio.h>
#include <stdlib.h>
#include "matlaber/cuda_ops.h"
#include "matlaber/log.h"
#include "matlaber/progress.h"
#include "matlaber/rng.h"
#include "matlaber/vae.h"
#include "unet_profile.h"

#define TRY(x) do { if ((x) != MLB_OK) { fprintf(stderr, "bench_cuda_vae: %s\n", mlb_last_error()); exit(1); } } while (0)

static int cmp_double(const void* a, const void* b) {
    double x = *(const double*)a, y = *(const double*)b;
    return x < y ? -1 : x > y;
}

int main(int argc, char** argv) {
    int reps = argc > 1 ? atoi(argv[1]) : 3;
    if (reps < 1 || reps > 50) reps = 3;
    int n_gpu = 0;
    if (mlb_cuda_probe(&n_gpu) != MLB_OK || mlb_cuda_init(0) != MLB_OK) {
        printf("bench_cuda_vae: no CUDA device, nothing to measure (%s)\n", mlb_last_error());
        return 0;
    }
    char desc[256];
    TRY(mlb_cuda_describe(0, desc, sizeof desc));
    mlb_vae_config cfg = mlb_vae_sd_config();
    mlb_vae* v;
    TRY(mlb_vae_create(NULL, &cfg, &v));
    mlb_vae_init_random(v, 3, 1.0f);
    const int N = 9, H = 512, W = 512, h = H / 8, w = W / 8;
    size_t ni = (size_t)N * 3 * H * W, nz = (size_t)N * 4 * h * w;
    float *img = malloc(ni * 4), *dimg = calloc(ni, 4), *mean = malloc(nz * 4), *logvar = malloc(nz * 4);
    float *g = malloc(nz * 4), *out = malloc((size_t)3 * H * W * 4);
    if (!img || !dimg || !mean || !logvar || !g || !out) { fprintf(stderr, "bench_cuda_vae: out of memory\n"); return 1; }
    for (size_t i = 0; i < ni; i++) img[i] = (float)mlb_rng_uniform_f64(1, 0, i) * 2 - 1;
    for (size_t i = 0; i < nz; i++) g[i] = (float)mlb_rng_uniform_f64(1, 1, i) * 2 - 1;
    printf("bench_cuda_vae: %s; SD VAE, %.1f M parameters; median of %d after 1 warm-up, wall clock through the "
           "host-buffer API\n\n", desc, v->n_params / 1e6, reps);
    printf("%-6s %-34s %10s %12s\n", "prec", "call", "ms", "per image ms");
    const mlb_gemm_precision precs[3] = {MLB_GEMM_FP32, MLB_GEMM_TF32, MLB_GEMM_BF16};
    for (int pi = 0; pi < 3; pi++) {
        TRY(mlb_vae_use_device(v, MLB_DEVICE_CUDA, precs[pi]));
        mlb_vae_cache cache = {0};
        double te[50], tb[50], td[50];
        for (int r = -1; r < reps; r++) {
            double t0 = mlb_now_seconds();
            TRY(mlb_vae_encode(NULL, v, img, N, H, W, mean, logvar, &cache));
            double t1 = mlb_now_seconds();
            TRY(mlb_vae_encode_backward(NULL, v, &cache, g, NULL, dimg, NULL));
            double t2 = mlb_now_seconds();
            TRY(mlb_vae_decode(NULL, v, mean, 1, h, w, out, NULL));
            double t3 = mlb_now_seconds();
            if (r >= 0) { te[r] = (t1 - t0) * 1e3; tb[r] = (t2 - t1) * 1e3; td[r] = (t3 - t2) * 1e3; }
        }
        qsort(te, reps, sizeof te[0], cmp_double);
        qsort(tb, reps, sizeof tb[0], cmp_double);
        qsort(td, reps, sizeof td[0], cmp_double);
        const char* pn = mlb_gemm_precision_name(precs[pi]);
        printf("%-6s %-34s %10.1f %12.1f\n", pn, "encode 9 x 512^2 (with cache)", te[reps / 2], te[reps / 2] / N);
        printf("%-6s %-34s %10.1f %12.1f\n", pn, "encode backward 9 x 512^2", tb[reps / 2], tb[reps / 2] / N);
        printf("%-6s %-34s %10.1f %12.1f\n", pn, "decode 1 x 512^2", td[reps / 2], td[reps / 2]);
        size_t fr, tot;
        TRY(mlb_cuda_mem_info(&fr, &tot));
        printf("%-6s %-34s %10.1f GiB held after (cache of 9 images: %.1f GiB)\n", pn, "device memory",
               (tot - fr) / 1073741824.0, cache.capacity * 4.0 / 1073741824.0);
        fflush(stdout);
        mlb_vae_cache_free(&cache);
    }
    // where the bf16 time goes: one encode (with the cache) and one backward through the profiling
    // copy of the mirror's op table (unet_profile.h), each op synchronised
    {
        const mlb_backend* keep = v->mirror_ops;
        mlb_backend w;
        prof_begin = mlb_cuda_timer_begin;
        prof_end = mlb_cuda_timer_end;
        char conv[64];
        snprintf(conv, sizeof conv, "conv2d (%s)", profile_conv_path());
        const char* names[P_COUNT] = {conv, "linear (GEMM)", "attention (one head of 512)", "group norm",
                                      "glue (add, SiLU, copies)"};
        mlb_vae_cache cache = {0};
        for (int pass = 0; pass < 2; pass++) {
            profile_wrap(keep, &w);
            v->mirror_ops = &w;
            if (pass == 0) TRY(mlb_vae_encode(NULL, v, img, N, H, W, mean, logvar, &cache));
            else TRY(mlb_vae_encode_backward(NULL, v, &cache, g, NULL, dimg, NULL));
            v->mirror_ops = keep;
            printf("\nprofile, %s 9 x 512^2, bf16 (each op synchronised):\n", pass ? "encode backward" : "encode (with cache)");
            profile_print(names);
        }
        mlb_vae_cache_free(&cache);
    }
    mlb_vae_free(v);
    free(img); free(dimg); free(mean); free(logvar); free(g); free(out);
    return 0;
}
