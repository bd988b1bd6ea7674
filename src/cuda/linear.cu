// GEMMs through cuBLAS (row-major wrapper, fp32 / tf32 / fp16 / bf16 operands with fp32
// accumulation) and the linear layer on top: the contract of linear_forward/backward (nn_api.inc).
#include <cuda_bf16.h>
#include <cuda_fp16.h>
#include "common.cuh"

__global__ void convert_f16_kernel(__half* dst, const float* src, size_t n) {
    for (size_t i = (size_t)blockIdx.x * blockDim.x + threadIdx.x; i < n; i += (size_t)gridDim.x * blockDim.x)
        dst[i] = __float2half_rn(src[i]);
}
__global__ void convert_bf16_kernel(__nv_bfloat16* dst, const float* src, size_t n) {
    for (size_t i = (size_t)blockIdx.x * blockDim.x + threadIdx.x; i < n; i += (size_t)gridDim.x * blockDim.x)
        dst[i] = __float2bfloat16_rn(src[i]);
}

extern "C" mlb_status mlb_cuda_convert(void* dst, mlb_cuda_dtype dst_type, const float* src, size_t n) {
    if (!n) return MLB_OK;
    if (dst_type == MLB_DTYPE_F16) {
        convert_f16_kernel<<<mlb_grid(n, 256), 256>>>((__half*)dst, src, n);
        MLB_CUDA_LAUNCHED("convert_f16_kernel");
    } else if (dst_type == MLB_DTYPE_BF16) {
        convert_bf16_kernel<<<mlb_grid(n, 256), 256>>>((__nv_bfloat16*)dst, src, n);
        MLB_CUDA_LAUNCHED("convert_bf16_kernel");
    } else {
        MLB_CUDA_CHECK(cudaMemcpyAsync(dst, src, n * sizeof(float), cudaMemcpyDeviceToDevice, 0));
    }
    return MLB_OK;
}

static cudaDataType_t cuda_type(mlb_cuda_dtype t) {
    return t == MLB_DTYPE_F16 ? CUDA_R_16F : t == MLB_DTYPE_BF16 ? CUDA_R_16BF : CUDA_R_32F;
}

// Row-major C = alpha op(A) op(B) + beta C is column-major C^T = alpha op(B)^T op(A)^T + beta C^T:
// cuBLAS sees B first, with the same transpose flags, and the sizes N x M. batch > 1: the strided
// batched form (matrix i at A + i stride_a, ...; a stride of 0 reuses one matrix for every i).
extern "C" mlb_status mlb_cuda_gemm_batched(int trans_a, int trans_b, int M, int N, int K, float alpha, const void* A,
                                            int lda, long long stride_a, const void* B, int ldb, long long stride_b,
                                            float beta, float* C, int ldc, long long stride_c, int batch,
                                            mlb_cuda_dtype ab_type, mlb_gemm_precision prec) {
    if (M < 0 || N < 0 || K < 0 || batch < 0)
        return mlb_fail(MLB_ERR_ARG, "mlb_cuda_gemm: negative size %d x %d x %d (batch %d)", M, N, K, batch);
    if (M == 0 || N == 0 || batch == 0) return MLB_OK;
    cublasHandle_t h;
    MLB_TRY(mlb_cuda_cublas(&h));
    cublasComputeType_t compute = CUBLAS_COMPUTE_32F;
    if (ab_type == MLB_DTYPE_F32 && prec == MLB_GEMM_TF32) compute = CUBLAS_COMPUTE_32F_FAST_TF32;
    if (K == 0 && beta == 0.0f) {   // cuBLAS treats K = 0 as C = beta C; make that explicit for beta = 0 too
        for (int i = 0; i < batch; i++)
            MLB_CUDA_CHECK(cudaMemset2DAsync(C + (size_t)i * stride_c, (size_t)ldc * sizeof(float), 0,
                                             (size_t)N * sizeof(float), (size_t)M, 0));
        return MLB_OK;
    }
    cublasOperation_t opb = trans_b ? CUBLAS_OP_T : CUBLAS_OP_N, opa = trans_a ? CUBLAS_OP_T : CUBLAS_OP_N;
    cudaDataType_t t = cuda_type(ab_type);
    if (batch == 1)
        MLB_CUBLAS_CHECK(cublasGemmEx(h, opb, opa, N, M, K, &alpha, B, t, ldb, A, t, lda, &beta, C, CUDA_R_32F, ldc,
                                      compute, CUBLAS_GEMM_DEFAULT));
    else
        MLB_CUBLAS_CHECK(cublasGemmStridedBatchedEx(h, opb, opa, N, M, K, &alpha, B, t, ldb, stride_b, A, t, lda,
                                                    stride_a, &beta, C, CUDA_R_32F, ldc, stride_c, batch, compute,
                                                    CUBLAS_GEMM_DEFAULT));
    return MLB_OK;
}

extern "C" mlb_status mlb_cuda_gemm(int trans_a, int trans_b, int M, int N, int K, float alpha, const void* A, int lda,
                                    const void* B, int ldb, float beta, float* C, int ldc, mlb_cuda_dtype ab_type,
                                    mlb_gemm_precision prec) {
    return mlb_cuda_gemm_batched(trans_a, trans_b, M, N, K, alpha, A, lda, 0, B, ldb, 0, beta, C, ldc, 0, 1, ab_type,
                                 prec);
}

// A GEMM on float operands at precision prec: fp16/bf16 convert both operands into the scratch
// buffer first (one pass each), then run on the tensor cores with fp32 accumulation.
static mlb_status gemm_f32(int ta, int tb, int M, int N, int K, const float* A, int lda, size_t a_count, const float* B,
                           int ldb, size_t b_count, float beta, float* C, int ldc, mlb_gemm_precision prec) {
    if (prec != MLB_GEMM_FP16 && prec != MLB_GEMM_BF16)
        return mlb_cuda_gemm(ta, tb, M, N, K, 1.0f, A, lda, B, ldb, beta, C, ldc, MLB_DTYPE_F32, prec);
    mlb_cuda_dtype t = prec == MLB_GEMM_FP16 ? MLB_DTYPE_F16 : MLB_DTYPE_BF16;
    size_t a_bytes = (a_count * 2 + 255) / 256 * 256;
    void* s;
    MLB_TRY(mlb_cuda_scratch(&s, a_bytes + b_count * 2));
    char* a16 = (char*)s;
    char* b16 = a16 + a_bytes;
    MLB_TRY(mlb_cuda_convert(a16, t, A, a_count));
    MLB_TRY(mlb_cuda_convert(b16, t, B, b_count));
    return mlb_cuda_gemm(ta, tb, M, N, K, 1.0f, a16, lda, b16, ldb, beta, C, ldc, t, prec);
}

// out[b, :] = bias (or 0): the GEMM then adds with beta = 1.
__global__ void broadcast_rows_kernel(float* out, const float* bias, int B, int OC) {
    size_t n = (size_t)B * OC;
    for (size_t i = (size_t)blockIdx.x * blockDim.x + threadIdx.x; i < n; i += (size_t)gridDim.x * blockDim.x)
        out[i] = bias[i % OC];
}

// dbias[o] += sum_b dout[b, o], b in order (one thread per column: deterministic; adjacent threads
// read adjacent columns, so the loads coalesce).
__global__ void dbias_kernel(float* dbias, const float* dout, int B, int OC) {
    int o = blockIdx.x * blockDim.x + threadIdx.x;
    if (o >= OC) return;
    double s = 0;
    for (int b = 0; b < B; b++) s += dout[(size_t)b * OC + o];
    dbias[o] += (float)s;
}

extern "C" mlb_status mlb_cuda_linear_forward(float* out, const float* in, const float* weight, const float* bias, int B,
                                              int C, int OC, mlb_gemm_precision prec) {
    if (B < 0 || C < 0 || OC < 0) return mlb_fail(MLB_ERR_ARG, "mlb_cuda_linear_forward: bad shape B %d C %d OC %d", B, C, OC);
    if (B == 0 || OC == 0) return MLB_OK;
    float beta = 0.0f;
    if (bias) {
        broadcast_rows_kernel<<<mlb_grid((size_t)B * OC, 256), 256>>>(out, bias, B, OC);
        MLB_CUDA_LAUNCHED("broadcast_rows_kernel");
        beta = 1.0f;
    }
    // out[B,OC] = in[B,C] . weight[OC,C]^T
    return gemm_f32(0, 1, B, OC, C, in, C, (size_t)B * C, weight, C, (size_t)OC * C, beta, out, OC, prec);
}

extern "C" mlb_status mlb_cuda_linear_backward(float* din, float* dweight, float* dbias, const float* dout,
                                               const float* in, const float* weight, int B, int C, int OC,
                                               mlb_gemm_precision prec) {
    if (B < 0 || C < 0 || OC < 0) return mlb_fail(MLB_ERR_ARG, "mlb_cuda_linear_backward: bad shape B %d C %d OC %d", B, C, OC);
    if (B == 0 || OC == 0) return MLB_OK;
    if (C > 0) {
        // din[B,C] += dout[B,OC] . weight[OC,C]
        if (din) MLB_TRY(gemm_f32(0, 0, B, C, OC, dout, OC, (size_t)B * OC, weight, C, (size_t)OC * C, 1.0f, din, C, prec));
        // dweight[OC,C] += dout^T[OC,B] . in[B,C]
        if (dweight)
            MLB_TRY(gemm_f32(1, 0, OC, C, B, dout, OC, (size_t)B * OC, in, C, (size_t)B * C, 1.0f, dweight, C, prec));
    }
    if (dbias) {
        dbias_kernel<<<mlb_blocks(OC, 128), 128>>>(dbias, dout, B, OC);
        MLB_CUDA_LAUNCHED("dbias_kernel");
    }
    return MLB_OK;
}
