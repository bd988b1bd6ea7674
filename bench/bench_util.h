// Shared by the bench programs (not itself a bench): the machine's SGEMM rate, the reference the
// network benches compare against, and the peak resident memory.
#ifndef MATLABER_BENCH_UTIL_H
#define MATLABER_BENCH_UTIL_H
#include <cblas.h>
#include <omp.h>
#include <stdlib.h>
#include <sys/resource.h>
#include "matlaber/nn.h"
#include "matlaber/progress.h"
#include "matlaber/rng.h"

// GFLOP/s of one row-major M×K · K×N SGEMM on all OpenMP threads: the best of 3 runs after a
// warm-up (0 when out of memory). ours = 0: OpenBLAS threading itself (the peer, and the machine's
// reference rate); ours = 1: the program's mlb_gemm (fixed shards, src/nn/gemm.c); ours = 2:
// mlb_gemm_bf16 (the same shards, bf16 operands: fp32 where the CPU lacks AVX-512 BF16).
static inline double bench_gemm_rate(int M, int N, int K, int ours) {
    float *a = malloc((size_t)M * K * 4), *b = malloc((size_t)K * N * 4), *c = malloc((size_t)M * N * 4);
    if (!a || !b || !c) { free(a); free(b); free(c); return 0; }
    mlb_rng_fill_uniform(a, (size_t)M * K, 1, 1, 0, -1, 1);
    mlb_rng_fill_uniform(b, (size_t)K * N, 1, 2, 0, -1, 1);
    double best = 1e30;
    if (!ours) openblas_set_num_threads(omp_get_max_threads());
    for (int r = 0; r < 4; r++) {
        double t0 = mlb_now_seconds();
        if (ours == 2) mlb_gemm_bf16(MLB_NOTRANS, MLB_NOTRANS, M, N, K, 1, a, K, b, N, 0, c, N);
        else if (ours) mlb_gemm(MLB_NOTRANS, MLB_NOTRANS, M, N, K, 1, a, K, b, N, 0, c, N);
        else cblas_sgemm(CblasRowMajor, CblasNoTrans, CblasNoTrans, M, N, K, 1, a, K, b, N, 0, c, N);
        double dt = mlb_now_seconds() - t0;
        if (r && dt < best) best = dt;
    }
    openblas_set_num_threads(1);   // as the program keeps it (src/core/threads.c)
    free(a); free(b); free(c);
    return 2.0 * M * N * K / best / 1e9;
}
static inline double bench_sgemm_rate(int M, int N, int K) { return bench_gemm_rate(M, N, K, 0); }

// Peak resident memory of this process in MB (getrusage: kilobytes on Linux).
static inline double bench_peak_mb(void) {
    struct rusage r;
    getrusage(RUSAGE_SELF, &r);
    return r.ru_maxrss / 1024.0;
}

#endif
