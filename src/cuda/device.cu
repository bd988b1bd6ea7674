// The CUDA part: device queries, the context (cuBLAS handle, scratch), memory helpers, timers,
// and the elementwise Adam/AdamW step. Checked against the CPU by tests/test_cuda_*.c.
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include "common.cuh"

extern "C" int mlb_cuda_compiled(void) { return 1; }

extern "C" mlb_status mlb_cuda_probe(int* count) {
    *count = 0;
    MLB_CUDA_CHECK(cudaGetDeviceCount(count));
    if (*count == 0) return mlb_fail(MLB_ERR_DEVICE, "cudaGetDeviceCount: no CUDA device is visible");
    return MLB_OK;
}

extern "C" int mlb_cuda_device_count(void) {
    int n = 0;
    if (cudaGetDeviceCount(&n) != cudaSuccess) { cudaGetLastError(); return 0; }
    return n;
}

extern "C" mlb_status mlb_cuda_describe(int index, char* buf, size_t n) {
    cudaDeviceProp p;
    if (n) buf[0] = 0;
    MLB_CUDA_CHECK(cudaGetDeviceProperties(&p, index));
    snprintf(buf, n, "%s, %.1f GiB, sm_%d%d, %d SMs", p.name, (double)p.totalGlobalMem / (1 << 30), p.major, p.minor,
             p.multiProcessorCount);
    return MLB_OK;
}

// ---- context: one per process (the current device). Not thread-safe: ops are called from the
// host thread that drives the GPU.
static cublasHandle_t g_cublas;
static int g_cublas_device = -1;
static void* g_scratch;
static size_t g_scratch_bytes;
static int g_sync_each = -1;

extern "C" mlb_status mlb_cuda_init(int index) {
    MLB_CUDA_CHECK(cudaSetDevice(index));
    MLB_CUDA_CHECK(cudaFree(0));   // creates the context: fails here when the driver is missing
    return MLB_OK;
}

mlb_status mlb_cuda_cublas(cublasHandle_t* out) {
    int dev;
    MLB_CUDA_CHECK(cudaGetDevice(&dev));
    if (g_cublas && g_cublas_device != dev) {
        MLB_CUBLAS_CHECK(cublasDestroy(g_cublas));
        g_cublas = NULL;
    }
    if (!g_cublas) {
        MLB_CUBLAS_CHECK(cublasCreate(&g_cublas));
        g_cublas_device = dev;
    }
    *out = g_cublas;
    return MLB_OK;
}

mlb_status mlb_cuda_scratch(void** out, size_t bytes) {
    if (bytes > g_scratch_bytes) {
        if (g_scratch) MLB_CUDA_CHECK(cudaFree(g_scratch));
        g_scratch = NULL;
        g_scratch_bytes = 0;
        size_t want = bytes + bytes / 4;   // grow by 25% more than asked: fewer reallocations
        if (cudaMalloc(&g_scratch, want) != cudaSuccess) {   // the pool may hold what is missing
            (void)cudaGetLastError();
            g_scratch = NULL;
            MLB_TRY(mlb_cuda_trim());
            MLB_CUDA_CHECK(cudaMalloc(&g_scratch, want));
        }
        g_scratch_bytes = want;
    }
    *out = g_scratch;
    return MLB_OK;
}

mlb_status mlb_cuda_after_launch(const char* file, int line, const char* what) {
    cudaError_t e = cudaGetLastError();
    if (e == cudaSuccess) {
        if (g_sync_each < 0) {
            const char* s = getenv("MLB_CUDA_SYNC");
            g_sync_each = s && *s && strcmp(s, "0") != 0;
        }
        if (g_sync_each) e = cudaDeviceSynchronize();
    }
    if (e != cudaSuccess) {
        (void)cudaGetLastError();
        return mlb_fail(MLB_ERR_DEVICE, "%s:%d: %s: %s (%s)", mlb_cuda_file(file), line, what, cudaGetErrorString(e), cudaGetErrorName(e));
    }
    return MLB_OK;
}

extern "C" mlb_status mlb_cuda_sync(void) {
    MLB_CUDA_CHECK(cudaDeviceSynchronize());
    return MLB_OK;
}

// Buffers come from the device's stream-ordered pool (cudaMallocAsync on the default stream, which
// every op runs on), told to keep what is freed: the per-call activations (the UNet's and the VAE's
// arenas, the staging of inputs) are then reused from one call to the next instead of going back
// to the driver, and freeing no longer synchronises the device as cudaFree does. When the pool
// cannot grow, what it keeps is handed back to the driver and the request tried once more.
static int g_pool_device = -1;
static mlb_status keep_freed_memory(void) {
    int dev;
    MLB_CUDA_CHECK(cudaGetDevice(&dev));
    if (dev == g_pool_device) return MLB_OK;
    cudaMemPool_t pool;
    MLB_CUDA_CHECK(cudaDeviceGetDefaultMemPool(&pool, dev));
    uint64_t keep = UINT64_MAX;
    MLB_CUDA_CHECK(cudaMemPoolSetAttribute(pool, cudaMemPoolAttrReleaseThreshold, &keep));
    g_pool_device = dev;
    return MLB_OK;
}
extern "C" mlb_status mlb_cuda_trim(void) {
    int dev;
    cudaMemPool_t pool;
    MLB_CUDA_CHECK(cudaGetDevice(&dev));
    MLB_CUDA_CHECK(cudaDeviceGetDefaultMemPool(&pool, dev));
    MLB_CUDA_CHECK(cudaDeviceSynchronize());
    MLB_CUDA_CHECK(cudaMemPoolTrimTo(pool, 0));
    return MLB_OK;
}
extern "C" mlb_status mlb_cuda_malloc(void** ptr, size_t bytes) {
    *ptr = NULL;
    if (cudaMallocAsync(ptr, bytes ? bytes : 1, 0) != cudaSuccess) {
        (void)cudaGetLastError();
        *ptr = NULL;
        if (g_pool_device >= 0) MLB_TRY(mlb_cuda_trim());   // the pool has kept memory: hand it back, try again
        MLB_CUDA_CHECK(cudaMallocAsync(ptr, bytes ? bytes : 1, 0));
    }
    mlb_status st = keep_freed_memory();
    if (st != MLB_OK) {
        (void)cudaFreeAsync(*ptr, 0);
        *ptr = NULL;
    }
    return st;
}
extern "C" mlb_status mlb_cuda_free(void* ptr) {
    if (ptr) MLB_CUDA_CHECK(cudaFreeAsync(ptr, 0));
    return MLB_OK;
}
static mlb_cuda_transfers transfers;   // the host thread's copies (the program drives the GPU from one)
extern "C" mlb_cuda_transfers mlb_cuda_transfers_get(void) { return transfers; }
extern "C" mlb_status mlb_cuda_copy_to_device(void* dst, const void* src, size_t bytes) {
    MLB_CUDA_CHECK(cudaMemcpy(dst, src, bytes, cudaMemcpyHostToDevice));
    transfers.up_bytes += bytes;
    transfers.copies++;
    return MLB_OK;
}
extern "C" mlb_status mlb_cuda_copy_to_host(void* dst, const void* src, size_t bytes) {
    MLB_CUDA_CHECK(cudaMemcpy(dst, src, bytes, cudaMemcpyDeviceToHost));
    transfers.down_bytes += bytes;
    transfers.copies++;
    return MLB_OK;
}
extern "C" mlb_status mlb_cuda_copy_d2d(void* dst, const void* src, size_t bytes) {
    MLB_CUDA_CHECK(cudaMemcpyAsync(dst, src, bytes, cudaMemcpyDeviceToDevice, 0));
    return MLB_OK;
}
extern "C" mlb_status mlb_cuda_memset(void* dst, int value, size_t bytes) {
    MLB_CUDA_CHECK(cudaMemsetAsync(dst, value, bytes, 0));
    return MLB_OK;
}
extern "C" mlb_status mlb_cuda_mem_info(size_t* free_bytes, size_t* total_bytes) {
    MLB_CUDA_CHECK(cudaMemGetInfo(free_bytes, total_bytes));
    return MLB_OK;
}

// splitmix64 of (seed, i): a cheap counter hash for test and benchmark inputs.
__global__ void fill_uniform_kernel(float* dst, size_t n, uint64_t seed, float lo, float hi) {
    for (size_t i = (size_t)blockIdx.x * blockDim.x + threadIdx.x; i < n; i += (size_t)gridDim.x * blockDim.x) {
        uint64_t z = seed * 0x9E3779B97F4A7C15ull + i + 1;
        z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
        z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
        z ^= z >> 31;
        float u = (float)(z >> 40) * (1.0f / 16777216.0f);
        dst[i] = lo + (hi - lo) * u;
    }
}

extern "C" mlb_status mlb_cuda_fill_uniform(float* dst, size_t n, uint64_t seed, float lo, float hi) {
    if (!n) return MLB_OK;
    fill_uniform_kernel<<<mlb_grid(n, 256), 256>>>(dst, n, seed, lo, hi);
    MLB_CUDA_LAUNCHED("fill_uniform_kernel");
    return MLB_OK;
}

static cudaEvent_t g_ev[2];
extern "C" mlb_status mlb_cuda_timer_begin(void) {
    if (!g_ev[0]) {
        MLB_CUDA_CHECK(cudaEventCreate(&g_ev[0]));
        MLB_CUDA_CHECK(cudaEventCreate(&g_ev[1]));
    }
    MLB_CUDA_CHECK(cudaEventRecord(g_ev[0], 0));
    return MLB_OK;
}
extern "C" mlb_status mlb_cuda_timer_end(double* ms) {
    float t = 0;
    *ms = 0;
    if (!g_ev[0]) return mlb_fail(MLB_ERR_ARG, "mlb_cuda_timer_end without mlb_cuda_timer_begin");
    MLB_CUDA_CHECK(cudaEventRecord(g_ev[1], 0));
    MLB_CUDA_CHECK(cudaEventSynchronize(g_ev[1]));
    MLB_CUDA_CHECK(cudaEventElapsedTime(&t, g_ev[0], g_ev[1]));
    *ms = t;
    return MLB_OK;
}

// ---- Adam / AdamW: the CPU's adam_update (src/nn/ops.c) with the same folded constants, so each
// step's float arithmetic is the same up to sqrtf/division rounding (both correctly rounded).
__global__ void adam_kernel(float* params, const float* grads, float* m, float* v, size_t n, float step,
                            float inv_sqrt_bc2, float eps, float beta1, float beta2, float one_minus_b1,
                            float one_minus_b2, float decay, float l2) {
    for (size_t i = (size_t)blockIdx.x * blockDim.x + threadIdx.x; i < n; i += (size_t)gridDim.x * blockDim.x) {
        float p = params[i];
        float g = __fadd_rn(grads[i], __fmul_rn(l2, p));
        p = __fmul_rn(p, decay);
        float mi = __fadd_rn(__fmul_rn(beta1, m[i]), __fmul_rn(one_minus_b1, g));
        float vi = __fadd_rn(__fmul_rn(beta2, v[i]), __fmul_rn(__fmul_rn(one_minus_b2, g), g));
        m[i] = mi;
        v[i] = vi;
        float den = __fadd_rn(__fmul_rn(__fsqrt_rn(vi), inv_sqrt_bc2), eps);
        params[i] = __fsub_rn(p, __fmul_rn(step, __fdiv_rn(mi, den)));
    }
}

extern "C" mlb_status mlb_cuda_adam_update(float* params, const float* grads, float* m, float* v, size_t n,
                                           const mlb_adam_config* cfg, long t) {
    if (t < 1) return mlb_fail(MLB_ERR_ARG, "adam step %ld must be >= 1", t);
    double lr = cfg->lr, b1 = cfg->beta1, b2 = cfg->beta2, wd = cfg->weight_decay;
    double bc1 = 1.0 - pow(b1, (double)t), bc2 = 1.0 - pow(b2, (double)t);
    float step = (float)(lr / bc1), inv_sqrt_bc2 = (float)(1.0 / sqrt(bc2));
    float decay = cfg->decoupled ? (float)(1.0 - lr * wd) : 1.0f, l2 = cfg->decoupled ? 0.0f : (float)wd;
    if (!n) return MLB_OK;
    adam_kernel<<<mlb_grid(n, 256), 256>>>(params, grads, m, v, n, step, inv_sqrt_bc2, (float)cfg->eps, (float)b1,
                                           (float)b2, (float)(1.0 - b1), (float)(1.0 - b2), decay, l2);
    MLB_CUDA_LAUNCHED("adam_kernel");
    return MLB_OK;
}
