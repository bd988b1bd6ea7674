// SD VAE encoder throughput on this machine: forward, and forward + backward to the image (what
// score distillation runs per view), for one image at 64², 128² and 256² with the tiny fixture VAE
// (../shared/data/sd_reference/sd1_diffusers/vae) when present; the same for the real SD VAE
// architecture with random weights at small sizes; and an estimate for the real VAE at 512² from
// the GEMM FLOP count and this machine's measured GEMM rate. Prints tables; see docs/vae.md.
//   build/bench/bench_vae [tiny-vae-path] [--sd512]    (--sd512 also times the real size at 512²)
//   build/bench/bench_vae --profile S [--batch B] [--precision fp32|bf16] [VAE]: only where the time of the
//     real VAE (or the VAE given) goes at B x S² (encode with its cache, its backward to the image,
//     decode), each op of the CPU's table timed.
#include <cblas.h>
#include <omp.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>
#include "bench_util.h"
#include "unet_profile.h"
#include "matlaber/progress.h"
#include "matlaber/rng.h"
#include "matlaber/threads.h"
#include "matlaber/vae.h"

// GEMM FLOPs of the encoder forward and of its backward to the image (weights frozen): every conv
// 2*OC*C*KH*KW*OH*OW (its data gradient the same), attention 4*T^2*C + 8*T*C^2 forward and
// 10*T^2*C + 8*T*C^2 backward (scores recomputed). GroupNorm/SiLU/adds are memory-bound, not counted.
static void encoder_flops(const mlb_vae_config* g, int H, int W, double* fwd, double* bwd) {
    double f = 0, b = 0;
#define CONV(C, OC, K, OH, OW) do { double x_ = 2.0 * (OC) * (C) * (K) * (K) * (double)(OH) * (OW); f += x_; b += x_; } while (0)
    CONV(g->in_channels, g->block_out[0], 3, H, W);
    for (int l = 0; l < g->n_levels; l++) {
        for (int j = 0; j < g->layers_per_block; j++) {
            int cin = j ? g->block_out[l] : g->block_out[l ? l - 1 : 0], c = g->block_out[l];
            CONV(cin, c, 3, H, W);
            CONV(c, c, 3, H, W);
            if (cin != c) CONV(cin, c, 1, H, W);
        }
        if (l < g->n_levels - 1) { H /= 2; W /= 2; CONV(g->block_out[l], g->block_out[l], 3, H, W); }
    }
    int C = g->block_out[g->n_levels - 1];
    double T = (double)H * W;
    for (int k = 0; k < 4; k++) CONV(C, C, 3, H, W);
    f += 4 * T * T * C + 8 * T * C * C;
    b += 10 * T * T * C + 8 * T * C * C;
    CONV(C, 2 * g->latent_channels, 3, H, W);
    CONV(2 * g->latent_channels, 2 * g->latent_channels, 1, H, W);
#undef CONV
    *fwd = f;
    *bwd = b;
}

// Median-free best-of timing of `reps` runs after one warm-up: forward only, and forward with
// the cache + backward.
static int time_encoder(const mlb_vae* v, int S, int reps, double* t_fwd, double* t_both, size_t* cache_bytes) {
    size_t n = (size_t)v->cfg.in_channels * S * S;
    int h = mlb_vae_latent_size(&v->cfg, S);
    size_t nz = (size_t)v->cfg.latent_channels * h * h;
    float* img = malloc(n * sizeof(float));
    float* dimg = calloc(n, sizeof(float));
    float* mean = malloc(nz * sizeof(float));
    float* g = malloc(nz * sizeof(float));
    mlb_rng_fill_uniform(img, n, 3, 1, 0, -1, 1);
    mlb_rng_fill_normal(g, nz, 3, 2, 0, 0, 1);
    mlb_vae_cache cache = {0};
    *t_fwd = *t_both = 1e30;
    for (int r = 0; r <= reps; r++) {
        double t0 = mlb_now_seconds();
        if (mlb_vae_encode(NULL, v, img, 1, S, S, mean, NULL, NULL)) goto fail;
        double t1 = mlb_now_seconds();
        if (mlb_vae_encode(NULL, v, img, 1, S, S, mean, NULL, &cache)) goto fail;
        if (mlb_vae_encode_backward(NULL, v, &cache, g, NULL, dimg, NULL)) goto fail;
        double t2 = mlb_now_seconds();
        if (r > 0 || reps == 0) {
            if (t1 - t0 < *t_fwd) *t_fwd = t1 - t0;
            if (t2 - t1 < *t_both) *t_both = t2 - t1;
        }
    }
    *cache_bytes = cache.capacity * sizeof(float);
    mlb_vae_cache_free(&cache);
    free(img); free(dimg); free(mean); free(g);
    return 0;
fail:
    fprintf(stderr, "bench_vae: %s\n", mlb_last_error());
    mlb_vae_cache_free(&cache);
    free(img); free(dimg); free(mean); free(g);
    return 1;
}

// The VAE named on the command line (an argument that is no option nor an option's value), or NULL.
static const char* positional_path(int argc, char** argv) {
    for (int i = 1; i < argc; i++) {
        if (argv[i][0] != '-') return argv[i];
        if (strcmp(argv[i], "--sd512")) i++;   // every other option takes a value
    }
    return NULL;
}

static const char* find_tiny(int argc, char** argv) {
    static char p[2048];
    struct stat s;
    if (positional_path(argc, argv)) return positional_path(argc, argv);
    const char* env = getenv("MLB_SHARED_DATA");
    const char* bases[] = {env, "../shared/data", "../../shared/data", "../../../shared/data"};
    for (int i = 0; i < 4; i++) {
        if (!bases[i]) continue;
        snprintf(p, sizeof p, "%s/sd_reference/sd1_diffusers/vae", bases[i]);
        if (stat(p, &s) == 0) return p;
    }
    return NULL;
}

// Where the real SD VAE's time goes at S² on the CPU: encode (with the cache), its backward to the
// image and decode, once each through the profiling copy of the CPU's op table (unet_profile.h),
// after a first encode + backward that is not timed.
static int profile_sd_vae(int S, int B, const char* path, mlb_gemm_precision prec) {
    mlb_vae_config g = mlb_vae_sd_config();
    mlb_vae* v = NULL;
    mlb_status made = S % 8 || B < 1 ? MLB_ERR_ARG : path ? mlb_vae_load(path, NULL, &v) : mlb_vae_create(NULL, &g, &v);
    if (made || mlb_vae_use_device(v, MLB_DEVICE_CPU, prec)) {
        fprintf(stderr, "bench_vae: --profile %d: %s\n", S,
                S % 8 || B < 1 ? "the size must be a multiple of 8, the batch positive" : mlb_last_error());
        mlb_vae_free(v);
        return 1;
    }
    if (path) g = v->cfg;
    else mlb_vae_init_random(v, 1, 1.0f);
    int h = mlb_vae_latent_size(&g, S);
    size_t ni = (size_t)B * 3 * S * S, nz = (size_t)B * 4 * h * h;
    float *img = malloc(ni * 4), *dimg = calloc(ni, 4), *mean = malloc(nz * 4), *dm = malloc(nz * 4);
    mlb_rng_fill_uniform(img, ni, 3, 1, 0, -1, 1);
    mlb_rng_fill_normal(dm, nz, 3, 2, 0, 0, 1);
    prof_begin = profile_wall_begin;
    prof_end = profile_wall_end;
    const char* names[P_COUNT] = {"conv2d (im2col + GEMM)", "linear (GEMM)", "attention (one head of 512)",
                                  "group norm", "glue (add, SiLU, copies)"};
    const char* what[3] = {"encode (with cache)", "encode backward to the image", "decode"};
    const mlb_backend* keep = v->mirror_ops;
    mlb_backend w;
    mlb_vae_cache cache = {0};
    // one encode + backward first, unprofiled: an SDS loop's steady state (the cache, with the
    // scratch at its end, allocated and its pages mapped by an earlier step)
    int rc = mlb_vae_encode(NULL, v, img, B, S, S, mean, NULL, &cache) || mlb_vae_encode_backward(NULL, v, &cache, dm, NULL, dimg, NULL);
    if (rc) fprintf(stderr, "bench_vae: warm-up: %s\n", mlb_last_error());
    for (int pass = 0; pass < 3 && !rc; pass++) {
        profile_wrap(keep ? keep : mlb_backend_cpu(), &w);
        v->mirror_ops = &w;
        double t0 = mlb_now_seconds();
        mlb_status s = pass == 0 ? mlb_vae_encode(NULL, v, img, B, S, S, mean, NULL, &cache)
                     : pass == 1 ? mlb_vae_encode_backward(NULL, v, &cache, dm, NULL, dimg, NULL)
                                 : mlb_vae_decode(NULL, v, mean, B, h, h, img, NULL);
        double dt = mlb_now_seconds() - t0;
        v->mirror_ops = keep;
        if (s) { fprintf(stderr, "bench_vae: %s: %s\n", what[pass], mlb_last_error()); rc = 1; break; }
        printf("\nprofile, %s VAE %s, %d x %d², %s GEMMs on the CPU (%.2f s):\n", path ? path : "SD", what[pass], B, S,
               mlb_gemm_precision_name(prec), dt);
        profile_print(names);
    }
    mlb_vae_cache_free(&cache);
    free(img); free(dimg); free(mean); free(dm);
    mlb_vae_free(v);
    return rc;
}

int main(int argc, char** argv) {
    mlb_runtime_restart(argv);   // the program's runtime settings (threads.h; docs/vae.md, "Threads")
    int sd512 = 0, profile_size = 0, profile_batch = 1;
    mlb_gemm_precision prec = MLB_GEMM_FP32;
    for (int i = 1; i < argc; i++) {
        if (!strcmp(argv[i], "--sd512")) sd512 = 1;
        else if (i + 1 < argc && !strcmp(argv[i], "--profile")) profile_size = atoi(argv[++i]);
        else if (i + 1 < argc && !strcmp(argv[i], "--batch")) profile_batch = atoi(argv[++i]);
        else if (i + 1 < argc && !strcmp(argv[i], "--precision") && mlb_gemm_precision_parse(argv[++i], &prec)) {
            fprintf(stderr, "bench_vae: %s\n", mlb_last_error());
            return 2;
        }
    }
    if (profile_size > 0) return profile_sd_vae(profile_size, profile_batch, positional_path(argc, argv), prec);
    int threads = omp_get_max_threads();
    mlb_set_threads(threads);
    const char* wp = getenv("OMP_WAIT_POLICY");
    printf("SD VAE encoder, 1 image, %d threads, OpenBLAS kernels %s, OMP_WAIT_POLICY %s\n\n", threads,
           mlb_blas_corename(), wp ? wp : "(unset)");
    // GEMM shapes of the dominant convs: 128->128 3x3 at 512² (one im2col band) and 512->512 at 64².
    double r1 = bench_sgemm_rate(128, 3640, 1152), r2 = bench_sgemm_rate(512, 896, 4608), r3 = bench_sgemm_rate(512, 4096, 512);
    double rate = (r1 + r2) / 2;
    printf("sgemm: %.1f GFLOP/s (128x1152 . 1152x3640), %.1f (512x4608 . 4608x896), %.1f (attention 512x512 . 512x4096)\n\n",
           r1, r2, r3);

    const char* tiny = find_tiny(argc, argv);
    mlb_vae* v = NULL;
    if (tiny && mlb_vae_load(tiny, NULL, &v) == MLB_OK) {
        printf("tiny fixture VAE (%s)\n\n", v->source);
        printf("| image | latent | forward ms | forward + backward ms | cache MB | GFLOP fwd / fwd+bwd |\n");
        printf("|------:|-------:|-----------:|----------------------:|---------:|--------------------:|\n");
        int sizes[] = {64, 128, 256};
        for (int i = 0; i < 3; i++) {
            double tf, tb, ff, fb;
            size_t cb;
            if (time_encoder(v, sizes[i], 5, &tf, &tb, &cb)) return 1;
            encoder_flops(&v->cfg, sizes[i], sizes[i], &ff, &fb);
            printf("| %3d² | %3d² | %10.1f | %21.1f | %8.1f | %8.2f / %.2f |\n", sizes[i], sizes[i] / 8, tf * 1e3, tb * 1e3,
                   cb / 1e6, ff / 1e9, (ff + fb) / 1e9);
        }
        mlb_vae_free(v);
        printf("\n");
    } else {
        printf("tiny fixture VAE not found (pass its folder, or set MLB_SHARED_DATA): skipped\n\n");
        mlb_clear_error();
    }

    mlb_vae_config sd = mlb_vae_sd_config();
    if (mlb_vae_create(NULL, &sd, &v) != MLB_OK) { fprintf(stderr, "bench_vae: %s\n", mlb_last_error()); return 1; }
    mlb_vae_init_random(v, 1, 1.0f);
    printf("real SD VAE architecture (128, 256, 512, 512), random weights, %zu parameters (%.0f MB float)\n\n",
           v->n_params, v->n_params * 4.0 / 1e6);
    printf("| image | forward s | fwd+bwd s | GFLOP fwd / fwd+bwd | achieved GFLOP/s fwd / fwd+bwd | cache MB |\n");
    printf("|------:|----------:|----------:|--------------------:|-------------------------------:|---------:|\n");
    int real_sizes[] = {64, 128, 512};
    double ach_f = 0, ach_b = 0;
    for (int i = 0; i < (sd512 ? 3 : 2); i++) {
        int S = real_sizes[i];
        double tf, tb, ff, fb;
        size_t cb;
        if (time_encoder(v, S, S >= 512 ? 0 : 2, &tf, &tb, &cb)) return 1;
        encoder_flops(&sd, S, S, &ff, &fb);
        ach_f = ff / tf / 1e9;
        ach_b = (ff + fb) / tb / 1e9;
        printf("| %3d² | %9.2f | %9.2f | %7.0f / %.0f | %14.1f / %.1f | %8.0f |\n", S, tf, tb, ff / 1e9, (ff + fb) / 1e9,
               ach_f, ach_b, cb / 1e6);
    }
    double ff, fb;
    encoder_flops(&sd, 512, 512, &ff, &fb);
    size_t cache = mlb_vae_cache_size(&sd, 1, 512, 512) * sizeof(float);
    printf("\nestimate for the real SD VAE encoder at 512² (1 image):\n");
    printf("  GEMM work: %.0f GFLOP forward, %.0f GFLOP backward to the image\n", ff / 1e9, fb / 1e9);
    printf("  at the sgemm rate (%.0f GFLOP/s): forward %.1f s, forward + backward %.1f s (lower bound)\n", rate,
           ff / rate / 1e9, (ff + fb) / rate / 1e9);
    printf("  at the rate achieved at %d² (%.0f / %.0f GFLOP/s): forward %.1f s, forward + backward %.1f s\n",
           real_sizes[sd512 ? 2 : 1], ach_f, ach_b, ff / ach_f / 1e9, (ff + fb) / ach_b / 1e9);
    printf("  memory: weights %.0f MB, backward cache %.0f MB, scratch about %.0f MB (forward) / %.0f MB (backward)\n",
           v->n_params * 4.0 / 1e6, cache / 1e6, 3 * 128.0 * 512 * 512 * 4 / 1e6, 4 * 128.0 * 512 * 512 * 4 / 1e6);
    mlb_vae_free(v);
    return 0;
}
