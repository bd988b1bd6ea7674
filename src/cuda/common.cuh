// Private to src/cuda: the error checks every CUDA and cuBLAS call goes through, the shared
// context (cuBLAS handle, scratch buffer) and launch helpers.
#ifndef MLB_CUDA_COMMON_CUH
#define MLB_CUDA_COMMON_CUH
#include <cublas_v2.h>
#include <cuda_runtime.h>
#include <stddef.h>
#include <stdint.h>
#include <string.h>
extern "C" {
#include "matlaber/cuda_ops.h"
#include "matlaber/device.h"
#include "matlaber/error.h"
}

// __FILE__ from "src/cuda/" on (nvcc gives the absolute path).
static inline const char* mlb_cuda_file(const char* f) {
    const char* p = strstr(f, "src/cuda/");
    return p ? p : f;
}
// A failed CUDA runtime call becomes MLB_ERR_DEVICE naming the file, line, the call and CUDA's
// own message ("src/cuda/linear.cu:42: cudaMalloc(&p, bytes): out of memory"). The sticky
// per-thread error is cleared so the next call starts clean.
#define MLB_CUDA_CHECK(call) do { cudaError_t mlb_e_ = (call); \
    if (mlb_e_ != cudaSuccess) { (void)cudaGetLastError(); \
        return mlb_fail(MLB_ERR_DEVICE, "%s:%d: %s: %s (%s)", mlb_cuda_file(__FILE__), __LINE__, #call, \
                        cudaGetErrorString(mlb_e_), cudaGetErrorName(mlb_e_)); } } while (0)
#define MLB_CUBLAS_CHECK(call) do { cublasStatus_t mlb_s_ = (call); \
    if (mlb_s_ != CUBLAS_STATUS_SUCCESS) \
        return mlb_fail(MLB_ERR_DEVICE, "%s:%d: %s: %s (%s)", mlb_cuda_file(__FILE__), __LINE__, #call, \
                        cublasGetStatusString(mlb_s_), cublasGetStatusName(mlb_s_)); } while (0)
// After every kernel launch: the launch error now; with MLB_CUDA_SYNC=1 in the environment also
// the kernel's own execution error (synchronising), so a fault is reported at the op that caused
// it instead of at the next synchronising call.
#define MLB_CUDA_LAUNCHED(what) MLB_TRY(mlb_cuda_after_launch(__FILE__, __LINE__, what))

mlb_status mlb_cuda_after_launch(const char* file, int line, const char* what);
// The shared cuBLAS handle of the current device (created on first use).
mlb_status mlb_cuda_cublas(cublasHandle_t* out);
// Scratch device memory of at least `bytes`, owned by the context, valid until the next call
// (ops call it once each and use it only inside the call). Stream-ordered with the default stream.
mlb_status mlb_cuda_scratch(void** out, size_t bytes);

// scan_i32 with the caller's scratch for its tile sums (mlb_cuda_scan_i32_sums(n) int32s): for ops
// that scan inside a scratch buffer of their own (src/cuda/marching_tets.cu)
size_t mlb_cuda_scan_i32_sums(int n);
mlb_status mlb_cuda_scan_i32_into(int32_t* out, const int32_t* in, int n, int32_t* sums);
static inline unsigned mlb_blocks(size_t n, int threads) { return (unsigned)((n + threads - 1) / threads); }
// Grid-stride loops keep grids within the 2^31-1 block limit for any n.
static inline unsigned mlb_grid(size_t n, int threads) {
    size_t b = (n + threads - 1) / threads;
    return (unsigned)(b > 65535u * 32u ? 65535u * 32u : (b ? b : 1));
}
#endif
