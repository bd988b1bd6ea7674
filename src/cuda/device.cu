// The CUDA part: device queries and the first kernel (AdamW), checked against the CPU by
// tests/test_cuda_parity.c when a GPU is present.
#include <cuda_runtime.h>
#include <math.h>
#include <stdio.h>
extern "C" {
#include "matlaber/device.h"
}

#define CUDA_CHECK(call, what) do { cudaError_t e_ = (call); \
    if (e_ != cudaSuccess) return mlb_fail(MLB_ERR_DEVICE, "CUDA %s failed: %s", what, cudaGetErrorString(e_)); } while (0)

extern "C" int mlb_cuda_compiled(void) { return 1; }

extern "C" int mlb_cuda_device_count(void) {
    int n = 0;
    if (cudaGetDeviceCount(&n) != cudaSuccess) { cudaGetLastError(); return 0; }
    return n;
}

extern "C" mlb_status mlb_cuda_describe(int index, char* buf, size_t n) {
    cudaDeviceProp p;
    CUDA_CHECK(cudaGetDeviceProperties(&p, index), "cudaGetDeviceProperties");
    snprintf(buf, n, "%s, %.1f GiB, sm_%d%d", p.name, (double)p.totalGlobalMem / (1 << 30), p.major, p.minor);
    return MLB_OK;
}

// One thread per parameter; the bias corrections are computed once on the host in double.
__global__ void adam_kernel(float* params, const float* grads, float* m, float* v, size_t n, float lr,
                            float beta1, float beta2, float eps, float wd, int decoupled, float bc1, float bc2) {
    size_t i = (size_t)blockIdx.x * blockDim.x + threadIdx.x;
    if (i >= n) return;
    float g = grads[i], p = params[i];
    if (!decoupled) g += wd * p;
    float mi = beta1 * m[i] + (1.0f - beta1) * g;
    float vi = beta2 * v[i] + (1.0f - beta2) * g * g;
    m[i] = mi;
    v[i] = vi;
    float update = (mi / bc1) / (sqrtf(vi / bc2) + eps);
    if (decoupled) p -= lr * wd * p;
    params[i] = p - lr * update;
}

extern "C" mlb_status mlb_cuda_adam_update(float* params, const float* grads, float* m, float* v, size_t n,
                                           const mlb_adam_config* cfg, long t) {
    if (t < 1) return mlb_fail(MLB_ERR_ARG, "adam step %ld must be >= 1", t);
    float bc1 = (float)(1.0 - pow(cfg->beta1, (double)t)), bc2 = (float)(1.0 - pow(cfg->beta2, (double)t));
    int threads = 256;
    unsigned blocks = (unsigned)((n + threads - 1) / threads);
    if (n) adam_kernel<<<blocks, threads>>>(params, grads, m, v, n, (float)cfg->lr, (float)cfg->beta1,
                                            (float)cfg->beta2, (float)cfg->eps, (float)cfg->weight_decay,
                                            cfg->decoupled, bc1, bc2);
    CUDA_CHECK(cudaGetLastError(), "adam kernel launch");
    CUDA_CHECK(cudaDeviceSynchronize(), "adam kernel");
    return MLB_OK;
}

extern "C" mlb_status mlb_cuda_malloc(void** ptr, size_t bytes) { CUDA_CHECK(cudaMalloc(ptr, bytes), "cudaMalloc"); return MLB_OK; }
extern "C" mlb_status mlb_cuda_free(void* ptr) { CUDA_CHECK(cudaFree(ptr), "cudaFree"); return MLB_OK; }
extern "C" mlb_status mlb_cuda_copy_to_device(void* dst, const void* src, size_t bytes) {
    CUDA_CHECK(cudaMemcpy(dst, src, bytes, cudaMemcpyHostToDevice), "cudaMemcpy to device");
    return MLB_OK;
}
extern "C" mlb_status mlb_cuda_copy_to_host(void* dst, const void* src, size_t bytes) {
    CUDA_CHECK(cudaMemcpy(dst, src, bytes, cudaMemcpyDeviceToHost), "cudaMemcpy to host");
    return MLB_OK;
}
