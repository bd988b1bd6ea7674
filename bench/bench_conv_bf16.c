// The bf16 convolutions of a tiny-preset generation, shape by shape: models/matlaber-tiny's VAE
// encoder at 128² (4 views: forward, and the input gradient that score distillation runs back to the
// images) and its UNet at 16² latents (4 views x 2 for guidance: forward with the weight packed at
// load). Where a `generate --preset tiny` step spends its GEMM time; the packing of the im2col panels
// was as large as the multiply (perf). Prints a table: ms per call (best of reps after a warm-up) and
// GFLOP/s (2·OC·C·KH·KW·OH·OW·N per call), and the CPU time of all threads per call (the machine is
// shared: the wall clock counts the time other programs held the cores, the CPU time does not).
//   build/bench/bench_conv_bf16 [--reps 5]
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include "bench_util.h"
#include "matlaber/conv_ops.h"
#include "matlaber/threads.h"

typedef struct {
    const char* name;
    mlb_conv2d cv;
    int calls;   // per VAE encode / UNet forward
} shape;

// {N, C, H, W, OC, KH, KW, sh, sw, top, left, bottom, right}
#define C3(N, C, S, OC) {N, C, S, S, OC, 3, 3, 1, 1, 1, 1, 1, 1}
#define C1(N, C, S, OC) {N, C, S, S, OC, 1, 1, 1, 1, 0, 0, 0, 0}
#define DN(N, C, S) {N, C, S, S, C, 3, 3, 2, 2, 0, 0, 1, 1}      // the VAE's downsampling
#define DU(N, C, S) {N, C, S, S, C, 3, 3, 2, 2, 1, 1, 1, 1}      // the UNet's
static const shape vae[] = {
    {"vae conv_in 3->32 @128", C3(4, 3, 128, 32), 1},
    {"vae res 32->32 @128", C3(4, 32, 128, 32), 2},
    {"vae down 32 @128->64", DN(4, 32, 128), 1},
    {"vae res 32->64 @64", C3(4, 32, 64, 64), 1},
    {"vae res 64->64 @64", C3(4, 64, 64, 64), 1},
    {"vae short 1x1 32->64 @64", C1(4, 32, 64, 64), 1},
    {"vae down 64 @64->32", DN(4, 64, 64), 1},
    {"vae res 64->64 @32", C3(4, 64, 32, 64), 2},
    {"vae down 64 @32->16", DN(4, 64, 32), 1},
    {"vae res 64->64 @16", C3(4, 64, 16, 64), 6},
    {"vae conv_out 64->8 @16", C3(4, 64, 16, 8), 1},
};
static const shape unet[] = {
    {"unet conv_in 4->64 @16", C3(8, 4, 16, 64), 1},
    {"unet res 64->64 @16", C3(8, 64, 16, 64), 2},
    {"unet down 64 @16->8", DU(8, 64, 16), 1},
    {"unet res 128->128 @8", C3(8, 128, 8, 128), 3},
    {"unet res 128->128 @4", C3(8, 128, 4, 128), 8},
    {"unet up res 256->128 @4", C3(8, 256, 4, 128), 3},
    {"unet up res 192->128 @16", C3(8, 192, 16, 64), 1},
    {"unet short 1x1 256->128 @4", C1(8, 256, 4, 128), 3},
};

static double flops(const mlb_conv2d* c) {
    return 2.0 * c->N * c->OC * c->C * c->KH * c->KW * (double)mlb_conv2d_out_h(c) * mlb_conv2d_out_w(c);
}

static double cpu_seconds(void) {
    struct timespec t;
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t);
    return t.tv_sec + 1e-9 * t.tv_nsec;
}

// Best time of reps calls of one conv direction (dir 0: forward, 1: input gradient, 2: forward with
// the weight packed at load), after one untimed call.
static double time_conv(const mlb_conv2d* c, int dir, int reps, double* cpu) {
    const size_t ni = (size_t)c->N * c->C * c->H * c->W, no = (size_t)c->N * c->OC * mlb_conv2d_out_h(c) * mlb_conv2d_out_w(c);
    const int K = c->C * c->KH * c->KW;
    float *in = malloc(ni * 4), *out = malloc(no * 4), *w = malloc((size_t)c->OC * K * 4), *b = malloc((size_t)c->OC * 4);
    uint32_t* pw = malloc(mlb_bf16_conv_weight_words(c->OC, K) * 4);
    mlb_rng_fill_uniform(in, ni, 5, 1, 0, -1, 1);
    mlb_rng_fill_uniform(out, no, 5, 2, 0, -1, 1);
    mlb_rng_fill_uniform(w, (size_t)c->OC * K, 5, 3, 0, -0.1f, 0.1f);
    mlb_rng_fill_uniform(b, (size_t)c->OC, 5, 4, 0, -0.1f, 0.1f);
    if (dir == 2 && !mlb_bf16_pack_conv_weight(pw, w, c->OC, K)) dir = 0;
    double best = 1e30;
    *cpu = 1e30;
    for (int r = 0; r <= reps; r++) {
        double t0 = mlb_now_seconds(), c0 = cpu_seconds();
        mlb_status s = dir == 0   ? conv2d_forward_bf16(out, in, w, b, c, NULL)
                       : dir == 1 ? conv2d_backward_bf16(in, NULL, NULL, out, NULL, w, c, NULL)
                                  : conv2d_forward_bf16_packed(out, in, pw, b, c);
        double dt = mlb_now_seconds() - t0, dc = cpu_seconds() - c0;
        if (r && dc < *cpu) *cpu = dc;
        if (s != MLB_OK) { fprintf(stderr, "bench_conv_bf16: %s\n", mlb_last_error()); exit(1); }
        if (r && dt < best) best = dt;
    }
    free(in); free(out); free(w); free(b); free(pw);
    return best;
}

static double table(const char* title, const shape* s, int n, int unet_dirs, int reps, double* cpu) {
    printf("%s\n\n| conv | calls | forward ms | GFLOP/s | CPU ms | %s ms | GFLOP/s | CPU ms |\n"
           "|---|--:|--:|--:|--:|--:|--:|--:|\n", title, unet_dirs ? "forward, packed weight," : "input gradient");
    double total = 0, total_cpu = 0;
    for (int i = 0; i < n; i++) {
        double c0, c1, t0 = time_conv(&s[i].cv, 0, reps, &c0), t1 = time_conv(&s[i].cv, unet_dirs ? 2 : 1, reps, &c1);
        double f = flops(&s[i].cv);
        total += s[i].calls * (unet_dirs ? t1 : t0 + t1);
        total_cpu += s[i].calls * (unet_dirs ? c1 : c0 + c1);
        printf("| %s | %d | %.3f | %.1f | %.3f | %.3f | %.1f | %.3f |\n", s[i].name, s[i].calls, t0 * 1e3, f / t0 / 1e9,
               c0 * 1e3, t1 * 1e3, f / t1 / 1e9, c1 * 1e3);
    }
    printf("\nweighted by calls (%s): %.1f ms, CPU %.1f ms\n\n", unet_dirs ? "packed forward" : "forward + input gradient",
           total * 1e3, total_cpu * 1e3);
    *cpu = total_cpu;
    return total;
}

int main(int argc, char** argv) {
    mlb_runtime_restart(argv);   // the program's runtime settings (threads.h)
    int reps = 5;
    for (int i = 1; i < argc; i++) {
        if (i + 1 < argc && !strcmp(argv[i], "--reps")) reps = atoi(argv[++i]);
        else { fprintf(stderr, "usage: bench_conv_bf16 [--reps 5]\n"); return 2; }
    }
    mlb_set_threads(omp_get_max_threads());
    printf("bf16 convolutions of a tiny-preset step, %d threads, bf16 kernel %s\n\n", omp_get_max_threads(),
           mlb_gemm_bf16_native() ? "on" : "off (fp32 fallback)");
    double ca, cb, a = table("VAE encoder, 4 views at 128²", vae, (int)(sizeof vae / sizeof vae[0]), 0, reps, &ca);
    double b = table("UNet, 8 latents at 16²", unet, (int)(sizeof unet / sizeof unet[0]), 1, reps, &cb);
    printf("total: %.1f ms, CPU %.1f ms\n", (a + b) * 1e3, (ca + cb) * 1e3);
    return 0;
}
