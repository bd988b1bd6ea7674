// matlaber device: what this build and machine can compute on.
#include <omp.h>
#include <stdio.h>
#include <string.h>
#include "cli.h"
#include "matlaber/device.h"

int cmd_device(int argc, char** argv) {
    if (argc > 1 && (strcmp(argv[1], "--help") == 0 || strcmp(argv[1], "-h") == 0)) {
        printf("usage: matlaber device\n\nLists the CPU (threads) and, when this build has the CUDA part, the GPUs.\n");
        return 0;
    }
    if (argc > 1) return cli_usage_error("device", "unexpected argument '%s'", argv[1]);
    printf("cpu: %d threads (OpenMP)\n", omp_get_max_threads());
    if (!mlb_cuda_compiled()) { printf("cuda: not built (nvcc was not found at build time)\n"); return 0; }
    int n = mlb_cuda_device_count();
    if (n == 0) printf("cuda: built, no GPU visible\n");
    for (int i = 0; i < n; i++) {
        char desc[256];
        if (mlb_cuda_describe(i, desc, sizeof desc) == MLB_OK) printf("cuda:%d: %s\n", i, desc);
    }
    return 0;
}
