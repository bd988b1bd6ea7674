// The stand-ins of the CUDA part's device functions that include/matlaber/device.h declares
// (count, probe, memory, copies), used when the CUDA part is not built: each exists in both builds,
// failing with "built without CUDA" here, so callers need no #ifdef. With the CUDA part the real
// ones are in src/cuda/device.cu. Here in core, beside device.c that calls them, so that nothing
// core declares is defined in a folder above it; the op list's stand-ins are in src/nn/no_cuda.c.
#include <stddef.h>
#include "matlaber/device.h"

#ifndef MLB_HAVE_CUDA
static mlb_status no_cuda(const char* fn) {
    return mlb_fail(MLB_ERR_DEVICE, "%s: this build has no CUDA part (built without CUDA: nvcc was not found at build time)",
                    fn);
}
#define NO_CUDA return no_cuda(__func__)
int mlb_cuda_compiled(void) { return 0; }
int mlb_cuda_device_count(void) { return 0; }
mlb_status mlb_cuda_probe(int* count) { *count = 0; NO_CUDA; }
mlb_status mlb_cuda_describe(int index, char* buf, size_t n) { if (n) buf[0] = 0; NO_CUDA; }
mlb_status mlb_cuda_malloc(void** ptr, size_t bytes) { *ptr = NULL; NO_CUDA; }
mlb_status mlb_cuda_free(void* ptr) { if (!ptr) return MLB_OK; NO_CUDA; }
mlb_status mlb_cuda_copy_to_device(void* dst, const void* src, size_t bytes) { NO_CUDA; }
mlb_status mlb_cuda_copy_to_host(void* dst, const void* src, size_t bytes) { NO_CUDA; }
mlb_cuda_transfers mlb_cuda_transfers_get(void) { return (mlb_cuda_transfers){0, 0, 0}; }
mlb_status mlb_cuda_init(int index) { NO_CUDA; }
mlb_status mlb_cuda_trim(void) { NO_CUDA; }
#endif
