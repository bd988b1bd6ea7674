// The stand-ins used when the CUDA part is not built: every CUDA function exists in both builds,
// failing with "built without CUDA" here, so callers need no #ifdef. With the CUDA part the real
// ones are in src/cuda/*.cu. Here in nn rather than core because the op list (backend_ops.def)
// they are generated from names types of nn and render (docs/architecture.md "Layers"); the
// device functions that core's device.h declares have theirs in src/core/no_cuda_device.c.
#include <string.h>
#include "matlaber/cuda_ops.h"
#include "matlaber/device.h"

#ifndef MLB_HAVE_CUDA
static mlb_status no_cuda(const char* fn) {
    return mlb_fail(MLB_ERR_DEVICE, "%s: this build has no CUDA part (built without CUDA: nvcc was not found at build time)",
                    fn);
}
#define NO_CUDA return no_cuda(__func__)
// The backend's ops, from their list (backend_ops.def)
#define MLB_OP(name, cuda_fn, params) mlb_status cuda_fn params { NO_CUDA; }
#define MLB_GEMM_OP(name, cuda_fn, params, args) \
    mlb_status cuda_fn(MLB_ARGS params, mlb_gemm_precision prec) { NO_CUDA; }
#include "matlaber/backend_ops.def"
mlb_status mlb_cuda_sync(void) { NO_CUDA; }
mlb_status mlb_cuda_memset(void* dst, int value, size_t bytes) { NO_CUDA; }
mlb_status mlb_cuda_copy_d2d(void* dst, const void* src, size_t bytes) { NO_CUDA; }
mlb_status mlb_cuda_fill_uniform(float* dst, size_t n, uint64_t seed, float lo, float hi) { NO_CUDA; }
mlb_status mlb_cuda_timer_begin(void) { NO_CUDA; }
mlb_status mlb_cuda_timer_end(double* ms) { *ms = 0; NO_CUDA; }
mlb_status mlb_cuda_mem_info(size_t* free_bytes, size_t* total_bytes) { *free_bytes = *total_bytes = 0; NO_CUDA; }
mlb_status mlb_cuda_gemm(int trans_a, int trans_b, int M, int N, int K, float alpha, const void* A, int lda,
                         const void* B, int ldb, float beta, float* C, int ldc, mlb_cuda_dtype ab_type,
                         mlb_gemm_precision prec) { NO_CUDA; }
mlb_status mlb_cuda_gemm_batched(int trans_a, int trans_b, int M, int N, int K, float alpha, const void* A, int lda,
                                 long long stride_a, const void* B, int ldb, long long stride_b, float beta, float* C,
                                 int ldc, long long stride_c, int batch, mlb_cuda_dtype ab_type,
                                 mlb_gemm_precision prec) { NO_CUDA; }
void mlb_cuda_use_cudnn(int on) { (void)on; }
void mlb_cuda_use_flash(int on) { (void)on; }
void mlb_cuda_flash_rows(int rows) { (void)rows; }
int mlb_cuda_cudnn_version(void) { return 0; }
mlb_status mlb_cuda_convert(void* dst, mlb_cuda_dtype dst_type, const float* src, size_t n) { NO_CUDA; }
mlb_status mlb_cuda_activation_forward_d1(float* out, float* d1, const float* in, size_t n, mlb_activation act) { NO_CUDA; }
mlb_status mlb_cuda_envlight_upload(mlb_cuda_envlight* out, const mlb_envlight* light) {
    memset(out, 0, sizeof *out);
    NO_CUDA;
}
void mlb_cuda_envlight_free(mlb_cuda_envlight* l) { if (l) memset(l, 0, sizeof *l); }
mlb_status mlb_cuda_shade_forward(float* out, const float* kd, const float* ks, const float* kr, const float* n,
                                  const float* v, int N, const mlb_cuda_envlight* light, mlb_fresnel fresnel) { NO_CUDA; }
mlb_status mlb_cuda_shade_backward(float* dkd, float* dks, float* dkr, float* dn, float* dv, const float* dout,
                                   const float* kd, const float* ks, const float* kr, const float* n, const float* v,
                                   int N, const mlb_cuda_envlight* light, mlb_fresnel fresnel) { NO_CUDA; }
#endif
