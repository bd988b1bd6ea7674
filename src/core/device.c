// Device selection, and the stand-ins used when the CUDA part is not built.
#include "matlaber/device.h"
#include <string.h>

mlb_status mlb_device_parse(const char* name, mlb_device* out) {
    if (strcmp(name, "cpu") == 0) { *out = MLB_DEVICE_CPU; return MLB_OK; }
    if (strcmp(name, "auto") == 0) { *out = mlb_cuda_device_count() > 0 ? MLB_DEVICE_CUDA : MLB_DEVICE_CPU; return MLB_OK; }
    if (strcmp(name, "cuda") == 0) {
        if (!mlb_cuda_compiled())
            return mlb_fail(MLB_ERR_DEVICE, "--device cuda: this build has no CUDA part (nvcc was not found at build time); "
                            "install the CUDA toolkit at /usr/local/cuda and rebuild, or use --device cpu");
        if (mlb_cuda_device_count() == 0)
            return mlb_fail(MLB_ERR_DEVICE, "--device cuda: no NVIDIA GPU is visible (cudaGetDeviceCount found none); use --device cpu");
        *out = MLB_DEVICE_CUDA;
        return MLB_OK;
    }
    return mlb_fail(MLB_ERR_ARG, "unknown device '%s' (expected cpu, cuda or auto)", name);
}

#ifndef MLB_HAVE_CUDA
static mlb_status no_cuda(void) {
    return mlb_fail(MLB_ERR_DEVICE, "this build has no CUDA part (nvcc was not found at build time)");
}
int mlb_cuda_compiled(void) { return 0; }
int mlb_cuda_device_count(void) { return 0; }
mlb_status mlb_cuda_describe(int index, char* buf, size_t n) { if (n) buf[0] = 0; return no_cuda(); }
mlb_status mlb_cuda_adam_update(float* params, const float* grads, float* m, float* v, size_t n,
                                const mlb_adam_config* cfg, long t) { return no_cuda(); }
mlb_status mlb_cuda_malloc(void** ptr, size_t bytes) { *ptr = NULL; return no_cuda(); }
mlb_status mlb_cuda_free(void* ptr) { return no_cuda(); }
mlb_status mlb_cuda_copy_to_device(void* dst, const void* src, size_t bytes) { return no_cuda(); }
mlb_status mlb_cuda_copy_to_host(void* dst, const void* src, size_t bytes) { return no_cuda(); }
#endif
