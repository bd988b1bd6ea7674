// mlb_gemm (fixed shards, the same bits on any thread count) against OpenBLAS's own threading on
// the shapes the program runs: SD 1.5 UNet and VAE convolutions as im2col GEMMs, attention, and the
// field networks' MLP layers (forward and weight gradient), and mlb_gemm_bf16 (bf16 operands, fp32
// sums) on the same shards. Prints a table; docs/benchmarks.md keeps the results.
// Usage: bench_gemm [--threads N]
#include <stdio.h>
#include <string.h>
#include "bench_util.h"
#include "matlaber/cpu.h"
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

int main(int argc, char** argv) {
    int threads = 2;
    for (int i = 1; i < argc; i++)
        if (!strcmp(argv[i], "--threads") && i + 1 < argc) threads = atoi(argv[++i]);
    mlb_set_threads(threads);
    mlb_cpu_info cpu;
    mlb_cpu_detect(&cpu);
    printf("bench_gemm: %s, %d threads, OpenBLAS kernels %s, bf16 GEMM: %s\n\n", cpu.model, threads,
           mlb_blas_corename(), mlb_gemm_bf16_native() ? "AVX-512 BF16 kernel" : "none (fp32 fallback)");
    printf("| shape (M x N x K) | what | OpenBLAS threaded GFLOP/s | mlb_gemm GFLOP/s | ratio | mlb_gemm_bf16 "
           "GFLOP/s | bf16 / mlb_gemm |\n");
    printf("|---|---|---:|---:|---:|---:|---:|\n");
    for (size_t i = 0; i < sizeof shapes / sizeof shapes[0]; i++) {
        const bench_shape* s = &shapes[i];
        double peer = bench_gemm_rate(s->M, s->N, s->K, 0), ours = bench_gemm_rate(s->M, s->N, s->K, 1);
        double bf16 = bench_gemm_rate(s->M, s->N, s->K, 2);
        printf("| %d x %d x %d | %s | %.1f | %.1f | %.2f | %.1f | %.2f |\n", s->M, s->N, s->K, s->what, peer, ours,
               peer > 0 ? ours / peer : 0, bf16, ours > 0 ? bf16 / ours : 0);
        fflush(stdout);
    }
    return 0;
}
