// mlb_gemm (fixed shards, the same bits on any thread count) against OpenBLAS's own threading on
// the shapes the program runs: SD 1.5 UNet and VAE convolutions as im2col GEMMs, attention, and the
// field networks' MLP layers (forward and weight gradient), and mlb_gemm_bf16 (bf16 operands, fp32
// sums) on the same shards. Then the SD convolutions as the ops run them: fp32 (im2col + mlb_gemm)
// against bf16 (conv2d_forward_bf16 / conv2d_backward_bf16's input gradient: the implicit GEMM of
// src/nn/conv_bf16.c). On a CPU with AMX the bf16 kernel runs on its tiles, and again with them off
// (the AVX-512 BF16 kernel). Prints tables; docs/benchmarks.md keeps the results.
// Usage: bench_gemm [--threads N]
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "bench_util.h"
#include "matlaber/conv_ops.h"
#include "matlaber/cpu.h"
#include "matlaber/progress.h"
#include "matlaber/rng.h"
#include "matlaber/threads.h"

typedef struct { int M, N, K; const char* what; } bench_shape;
static const bench_shape shapes[] = {
    {320, 4096, 2880, "UNet 64² conv 3x3 320->320 (OC x HW x 9C)"},
    {640, 1024, 5760, "UNet 32² conv 3x3 640->640"},
    {1280, 256, 11520, "UNet 16² conv 3x3 1280->1280"},
    {4096, 320, 320, "UNet 64² attention projection (HW x C x C)"},
    {4096, 4096, 40, "UNet 64² attention scores, one head (HW x HW x 40)"},
    {4096, 1280, 320, "UNet 64² GEGLU up (HW x 4C.. x C)"},
    {128, 65536, 1152, "VAE 256² conv 3x3 128->128"},
    {65536, 32, 32, "field MLP layer, 64k points (B x 32 x 32)"},
    {32, 32, 65536, "field MLP weight gradient (32 x 32 x B)"},
};

typedef struct { int N, C, H, OC, K; const char* what; } conv_shape;
static const conv_shape convs[] = {
    {1, 128, 512, 128, 3, "VAE 512² 3x3 128->128"},
    {1, 256, 256, 256, 3, "VAE 256² 3x3 256->256"},
    {1, 512, 128, 512, 3, "VAE 128² 3x3 512->512"},
    {2, 320, 64, 320, 3, "UNet 64² 3x3 320->320, batch 2"},
    {2, 1280, 16, 1280, 3, "UNet 16² 3x3 1280->1280, batch 2"},
    {2, 2560, 8, 1280, 3, "UNet 8² 3x3 2560->1280, batch 2"},
    {2, 640, 64, 320, 1, "UNet 64² 1x1 640->320, batch 2"},
};

// GFLOP/s of one conv op (best of 2 after a warm-up): 0 forward fp32, 1 forward bf16, 2 input
// gradient fp32, 3 input gradient bf16.
static double conv_rate(const conv_shape* s, int which, float* in, float* w, float* out) {
    mlb_conv2d cv = mlb_conv2d_make(s->N, s->C, s->H, s->H, s->OC, s->K, 1, s->K / 2);
    double best = 1e30;
    for (int rep = 0; rep < 3; rep++) {
        double t0 = mlb_now_seconds();
        mlb_status st = which == 0   ? conv2d_forward(out, in, w, NULL, &cv, NULL)
                        : which == 1 ? conv2d_forward_bf16(out, in, w, NULL, &cv, NULL)
                        : which == 2 ? conv2d_backward(in, NULL, NULL, out, NULL, w, &cv, NULL)
                                     : conv2d_backward_bf16(in, NULL, NULL, out, NULL, w, &cv, NULL);
        double dt = mlb_now_seconds() - t0;
        if (st != MLB_OK) return 0;
        if (rep > 0 && dt < best) best = dt;
    }
    return 2.0 * s->N * s->C * s->OC * s->K * s->K * (double)s->H * s->H / best / 1e9;
}

int main(int argc, char** argv) {
    int threads = 2;
    for (int i = 1; i < argc; i++)
        if (!strcmp(argv[i], "--threads") && i + 1 < argc) threads = atoi(argv[++i]);
    mlb_set_threads(threads);
    mlb_cpu_info cpu;
    mlb_cpu_detect(&cpu);
    const int amx = mlb_gemm_bf16_amx();   // then the bf16 kernel is measured on AMX tiles and with them off
    printf("bench_gemm: %s, %d threads, OpenBLAS kernels %s, bf16 GEMM: %s\n\n", cpu.model, threads,
           mlb_blas_corename(), !mlb_gemm_bf16_native() ? "none (fp32 fallback)"
                                : amx ? "AMX tiles (and the AVX-512 BF16 kernel: AMX off)" : "AVX-512 BF16 kernel");
    printf("| shape (M x N x K) | what | OpenBLAS threaded GFLOP/s | mlb_gemm GFLOP/s | ratio | mlb_gemm_bf16 "
           "GFLOP/s | bf16 / mlb_gemm | bf16, AMX off | AMX / AVX-512 BF16 |\n");
    printf("|---|---|---:|---:|---:|---:|---:|---:|---:|\n");
    for (size_t i = 0; i < sizeof shapes / sizeof shapes[0]; i++) {
        const bench_shape* s = &shapes[i];
        double peer = bench_gemm_rate(s->M, s->N, s->K, 0), ours = bench_gemm_rate(s->M, s->N, s->K, 1);
        double bf16 = bench_gemm_rate(s->M, s->N, s->K, 2), avx = 0;
        if (amx) {
            mlb_gemm_bf16_force_amx_off(1);
            avx = bench_gemm_rate(s->M, s->N, s->K, 2);
            mlb_gemm_bf16_force_amx_off(0);
        }
        printf("| %d x %d x %d | %s | %.1f | %.1f | %.2f | %.1f | %.2f | %.1f | %.2f |\n", s->M, s->N, s->K, s->what,
               peer, ours, peer > 0 ? ours / peer : 0, bf16, ours > 0 ? bf16 / ours : 0, avx, avx > 0 ? bf16 / avx : 0);
        fflush(stdout);
    }
    printf("\n| convolution | fp32 forward GFLOP/s | bf16 forward | ratio | fp32 input gradient | bf16 input gradient "
           "| ratio | bf16 forward, AMX off |\n|---|---:|---:|---:|---:|---:|---:|---:|\n");
    for (size_t i = 0; i < sizeof convs / sizeof convs[0]; i++) {
        const conv_shape* s = &convs[i];
        size_t ni = (size_t)s->N * s->C * s->H * s->H, no = (size_t)s->N * s->OC * s->H * s->H;
        size_t nw = (size_t)s->OC * s->C * s->K * s->K;
        float *in = malloc(ni * sizeof(float)), *out = malloc(no * sizeof(float)), *w = malloc(nw * sizeof(float));
        if (!in || !out || !w) { fprintf(stderr, "bench_gemm: out of memory for %s\n", s->what); return 1; }
        mlb_rng_fill_uniform(in, ni, 1, 1, 0, -1, 1);
        mlb_rng_fill_uniform(w, nw, 1, 2, 0, -0.05f, 0.05f);
        double r[5] = {0};
        for (int k = 0; k < 4; k++) r[k] = conv_rate(s, k, in, w, out);
        if (amx) {
            mlb_gemm_bf16_force_amx_off(1);
            r[4] = conv_rate(s, 1, in, w, out);
            mlb_gemm_bf16_force_amx_off(0);
        }
        printf("| %s | %.1f | %.1f | %.2f | %.1f | %.1f | %.2f | %.1f |\n", s->what, r[0], r[1], r[0] > 0 ? r[1] / r[0] : 0,
               r[2], r[3], r[2] > 0 ? r[3] / r[2] : 0, r[4]);
        fflush(stdout);
        free(in); free(out); free(w);
    }
    return 0;
}
