// Device selection (--device), and the stand-ins used when the CUDA part is not built: every
// CUDA function exists in both builds, failing with "built without CUDA" here, so callers need no
// #ifdef. With the CUDA part the real ones are in src/cuda/*.cu.
#include "matlaber/device.h"
#include <stdlib.h>
#include <string.h>
#include "matlaber/cuda_ops.h"

static mlb_device current_device = MLB_DEVICE_CPU;

mlb_device mlb_device_current(void) { return current_device; }
const char* mlb_device_name(mlb_device d) { return d == MLB_DEVICE_CUDA ? "cuda" : "cpu"; }

#define NO_CUDA_HINT "install the CUDA toolkit at /usr/local/cuda and rebuild, or use --device cpu"

// "cuda" -> 0, "cuda:3" -> 3; -1 when name is not a cuda name, -2 when the index is malformed.
static int cuda_index(const char* name) {
    if (strncmp(name, "cuda", 4) != 0) return -1;
    if (name[4] == 0) return 0;
    if (name[4] != ':' || name[5] < '0' || name[5] > '9') return -2;
    char* end;
    long i = strtol(name + 5, &end, 10);
    if (*end || i > 1024) return -2;
    return (int)i;
}

static mlb_status require_cuda(const char* name, int index) {
    if (!mlb_cuda_compiled())
        return mlb_fail(MLB_ERR_DEVICE, "--device %s: this build has no CUDA part (built without CUDA: nvcc was not "
                        "found at build time); " NO_CUDA_HINT, name);
    int count = 0;
    if (mlb_cuda_probe(&count) != MLB_OK)
        return mlb_fail_context(MLB_ERR_DEVICE, "--device %s (use --device cpu)", name);
    if (index >= count)
        return mlb_fail(MLB_ERR_DEVICE, "--device %s: GPU %d asked for, %d visible; use --device cpu or cuda:0..%d", name,
                        index, count, count - 1);
    return MLB_OK;
}

mlb_status mlb_device_parse(const char* name, mlb_device* out) {
    if (!name) return mlb_fail(MLB_ERR_ARG, "device name is NULL (expected cpu, cuda or auto)");
    if (strcmp(name, "cpu") == 0) { *out = MLB_DEVICE_CPU; return MLB_OK; }
    if (strcmp(name, "auto") == 0) { *out = mlb_cuda_device_count() > 0 ? MLB_DEVICE_CUDA : MLB_DEVICE_CPU; return MLB_OK; }
    int idx = cuda_index(name);
    if (idx >= 0) {
        MLB_TRY(require_cuda(name, idx));
        *out = MLB_DEVICE_CUDA;
        return MLB_OK;
    }
    return mlb_fail(MLB_ERR_ARG, "unknown device '%s' (expected cpu, cuda, cuda:N or auto)", name);
}

mlb_status mlb_device_select(const char* name, mlb_device* out) {
    mlb_device d;
    MLB_TRY(mlb_device_parse(name, &d));
    if (d == MLB_DEVICE_CUDA) {
        int idx = cuda_index(name);
        if (idx < 0) idx = 0;   // "auto"
        mlb_status st = mlb_cuda_init(idx);
        if (st != MLB_OK) {
            if (strcmp(name, "auto") != 0) return mlb_fail_context(st, "--device %s (use --device cpu)", name);
            d = MLB_DEVICE_CPU;   // auto: a GPU that cannot be initialised means the CPU
        }
    }
    current_device = d;
    *out = d;
    return MLB_OK;
}

mlb_status mlb_device_option(const char* arg, mlb_device* out) {
    if (!arg) {
        arg = getenv("MATLABER_DEVICE");
        if (!arg || !*arg) arg = "auto";
    }
    return mlb_device_select(arg, out);
}

const char* mlb_gemm_precision_name(mlb_gemm_precision p) {
    switch (p) {
    case MLB_GEMM_FP32: return "fp32";
    case MLB_GEMM_TF32: return "tf32";
    case MLB_GEMM_FP16: return "fp16";
    case MLB_GEMM_BF16: return "bf16";
    }
    return "?";
}

mlb_status mlb_gemm_precision_parse(const char* name, mlb_gemm_precision* out) {
    for (int p = MLB_GEMM_FP32; p <= MLB_GEMM_BF16; p++)
        if (name && !strcmp(name, mlb_gemm_precision_name((mlb_gemm_precision)p))) {
            *out = (mlb_gemm_precision)p;
            return MLB_OK;
        }
    return mlb_fail(MLB_ERR_ARG, "--precision: expected fp16, bf16, tf32 or fp32, not '%s'", name ? name : "");
}

static mlb_gemm_precision current_precision = MLB_GEMM_FP16;
static int precision_chosen = 0;
void mlb_set_gemm_precision(mlb_gemm_precision p) { current_precision = p; precision_chosen = 1; }
mlb_gemm_precision mlb_gemm_precision_current(void) { return current_precision; }
int mlb_gemm_precision_chosen(void) { return precision_chosen; }

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
int mlb_cuda_compiled(void) { return 0; }
int mlb_cuda_device_count(void) { return 0; }
mlb_status mlb_cuda_probe(int* count) { *count = 0; NO_CUDA; }
mlb_status mlb_cuda_describe(int index, char* buf, size_t n) { if (n) buf[0] = 0; NO_CUDA; }
mlb_status mlb_cuda_malloc(void** ptr, size_t bytes) { *ptr = NULL; NO_CUDA; }
mlb_status mlb_cuda_free(void* ptr) { if (!ptr) return MLB_OK; NO_CUDA; }
mlb_status mlb_cuda_copy_to_device(void* dst, const void* src, size_t bytes) { NO_CUDA; }
mlb_status mlb_cuda_copy_to_host(void* dst, const void* src, size_t bytes) { NO_CUDA; }
mlb_status mlb_cuda_init(int index) { NO_CUDA; }
mlb_status mlb_cuda_sync(void) { NO_CUDA; }
mlb_status mlb_cuda_memset(void* dst, int value, size_t bytes) { NO_CUDA; }
mlb_status mlb_cuda_copy_d2d(void* dst, const void* src, size_t bytes) { NO_CUDA; }
mlb_status mlb_cuda_fill_uniform(float* dst, size_t n, uint64_t seed, float lo, float hi) { NO_CUDA; }
mlb_status mlb_cuda_timer_begin(void) { NO_CUDA; }
mlb_status mlb_cuda_timer_end(double* ms) { *ms = 0; NO_CUDA; }
mlb_status mlb_cuda_mem_info(size_t* free_bytes, size_t* total_bytes) { *free_bytes = *total_bytes = 0; NO_CUDA; }
mlb_status mlb_cuda_trim(void) { NO_CUDA; }
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
mlb_status mlb_cuda_attention_forward(float* out, const float* q, const float* k, const float* v, int ld, int B, int T,
                                      int C, int NH, int causal) { NO_CUDA; }
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
