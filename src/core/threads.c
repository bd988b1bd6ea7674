// "--threads N" is the OpenMP thread count. OpenBLAS (Debian's pthread build) keeps a pool of its
// own, which stays at one thread: mlb_gemm (src/nn/gemm.c) shares a GEMM out over OpenMP in
// shards fixed by the shape, so that the thread count never changes a result.
#include "matlaber/threads.h"
#include "matlaber/cpu.h"
#include <cblas.h>
#include <omp.h>
#include <stdlib.h>

void mlb_set_threads(int n) {
    if (n < 1) n = 1;
    omp_set_num_threads(n);
    openblas_set_num_threads(1);
}

int mlb_get_threads(void) { return omp_get_max_threads(); }

const char* mlb_blas_corename(void) { return openblas_get_corename(); }
const char* mlb_blas_config(void) { return openblas_get_config(); }

const char* mlb_blas_better_coretype(void) {
    const char* env = getenv("OPENBLAS_CORETYPE");
    if (env && *env) return NULL;   // the user chose
    mlb_cpu_info cpu;
    mlb_cpu_detect(&cpu);
    return mlb_blas_coretype_for(openblas_get_corename(), &cpu);
}
