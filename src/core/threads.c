// OpenBLAS (Debian's pthread build) keeps its own pool, which omp_set_num_threads does not
// reach; setting both keeps "--threads N" true for GEMMs as well as for our loops.
#include "matlaber/threads.h"
#include <cblas.h>
#include <omp.h>
#include <stdlib.h>
#include <string.h>

void mlb_set_threads(int n) {
    if (n < 1) n = 1;
    omp_set_num_threads(n);
    openblas_set_num_threads(n);
}

int mlb_get_threads(void) { return omp_get_max_threads(); }

const char* mlb_blas_corename(void) { return openblas_get_corename(); }

const char* mlb_blas_better_coretype(void) {
    const char* env = getenv("OPENBLAS_CORETYPE");
    if (env && *env) return NULL;   // the user chose
    const char* core = openblas_get_corename();
    if (!core || (strcmp(core, "Prescott") != 0 && strcmp(core, "Core2") != 0 && strcmp(core, "Nehalem") != 0 &&
                  strcmp(core, "Sandybridge") != 0))
        return NULL;
    __builtin_cpu_init();
    if (__builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512bw") && __builtin_cpu_supports("avx512vl"))
        return "SkylakeX";
    if (__builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma")) return "Haswell";
    return NULL;
}
