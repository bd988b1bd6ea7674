// matlaber device: what this build and machine can compute on.
#include <omp.h>
#include <stdlib.h>
#include <stdio.h>
#include <string.h>
#include "cli.h"
#include "matlaber/cpu.h"
#include "matlaber/nn.h"
#include "matlaber/device.h"
#include "matlaber/threads.h"

int cmd_device(int argc, char** argv) {
    if (argc > 1 && (strcmp(argv[1], "--help") == 0 || strcmp(argv[1], "-h") == 0)) {
        printf("usage: matlaber device\n\nLists the CPU (model, features, threads), the BLAS and its kernel family and,\n"
               "when this build has the CUDA part, the GPUs.\n");
        return 0;
    }
    if (argc > 1) return cli_usage_error("device", "unexpected argument '%s'", argv[1]);
    mlb_cpu_info cpu;
    mlb_cpu_detect(&cpu);
    char features[256];
    mlb_cpu_feature_string(&cpu, features, sizeof features);
    printf("cpu: %s (%s family %d model %d), %d threads (OpenMP)\n", cpu.model, cpu.vendor, cpu.family, cpu.model_id,
           omp_get_max_threads());
    printf("cpu features: %s\n", features);
    printf("bf16 GEMM (--precision bf16, the tiny models' default): %s\n",
           !mlb_gemm_bf16_native() ? "fp32 here (no AVX-512 BF16, or $MATLABER_CPU_BF16 off)"
           : mlb_gemm_bf16_amx()   ? "AMX tiles ($MATLABER_CPU_AMX=0: the AVX-512 BF16 kernel)"
           : cpu.amx_bf16          ? "AVX-512 BF16 kernel (AMX off: $MATLABER_CPU_AMX, or the OS refused the tile state)"
                                   : "AVX-512 BF16 kernel");
    printf("blas: %s; kernels %s%s\n", mlb_blas_config(), mlb_blas_corename(),
           getenv("MATLABER_BLAS_CHOSEN") ? " (chosen by matlaber from the CPU features)"
           : getenv("OPENBLAS_CORETYPE") ? " (set by $OPENBLAS_CORETYPE)" : "");
    if (!mlb_cuda_compiled()) { printf("cuda: not built (nvcc was not found at build time)\n"); return 0; }
    int n = mlb_cuda_device_count();
    if (n == 0) printf("cuda: built, no GPU visible\n");
    for (int i = 0; i < n; i++) {
        char desc[256];
        if (mlb_cuda_describe(i, desc, sizeof desc) == MLB_OK) printf("cuda:%d: %s\n", i, desc);
    }
    return 0;
}
