// Layer norm (transformer_ops.h) and group norm with a fused activation (conv_ops.h), forward.
// Statistics are two-pass sums in double like the CPU's, in a fixed reduction order (the same
// result on every run); the normalised value is computed in double and rounded once, as on the CPU.
#include "common.cuh"
#include "act.cuh"

__device__ __forceinline__ double warp_sum(double s) {
    for (int o = 16; o > 0; o >>= 1) s += __shfl_xor_sync(0xffffffffu, s, o);
    return s;
}

// One warp per row of C values.
__global__ void layernorm_kernel(float* out, float* mean, float* rstd, const float* in, const float* weight,
                                 const float* bias, int N, int C, float eps) {
    int warp = (blockIdx.x * blockDim.x + threadIdx.x) >> 5, lane = threadIdx.x & 31;
    if (warp >= N) return;
    const float* x = in + (size_t)warp * C;
    float* o = out + (size_t)warp * C;
    double m = 0, v = 0;
    for (int c = lane; c < C; c += 32) m += (double)x[c];
    m = warp_sum(m);
    m = C > 0 ? m / C : 0;
    for (int c = lane; c < C; c += 32) { double d = (double)x[c] - m; v += d * d; }
    v = warp_sum(v);
    v = C > 0 ? v / C : 0;
    double r = 1.0 / sqrt(v + (double)eps);
    for (int c = lane; c < C; c += 32) {
        float xh = (float)(((double)x[c] - m) * r);
        o[c] = __fadd_rn(__fmul_rn(xh, weight ? weight[c] : 1.0f), bias ? bias[c] : 0.0f);
    }
    if (lane == 0) {
        if (mean) mean[warp] = (float)m;
        if (rstd) rstd[warp] = (float)r;
    }
}

extern "C" mlb_status mlb_cuda_layernorm_forward(float* out, float* mean, float* rstd, const float* in,
                                                 const float* weight, const float* bias, int N, int C, float eps) {
    if (N < 0 || C < 0) return mlb_fail(MLB_ERR_ARG, "mlb_cuda_layernorm_forward: bad shape N %d C %d", N, C);
    if (N == 0) return MLB_OK;
    const int threads = 256, rows_per_block = threads / 32;
    layernorm_kernel<<<mlb_blocks(N, rows_per_block), threads>>>(out, mean, rstd, in, weight, bias, N, C, eps);
    MLB_CUDA_LAUNCHED("layernorm_kernel");
    return MLB_OK;
}

#define GN_THREADS 512
// Block sum in a fixed order: per-thread strided partial sums, warp trees, then warp 0 over the
// warps' sums. Every thread gets the total.
__device__ double block_sum(double s, double* shared) {
    int lane = threadIdx.x & 31, w = threadIdx.x >> 5;
    s = warp_sum(s);
    if (lane == 0) shared[w] = s;
    __syncthreads();
    if (w == 0) {
        double t = lane < (int)(blockDim.x >> 5) ? shared[lane] : 0.0;
        t = warp_sum(t);
        if (lane == 0) shared[32] = t;
    }
    __syncthreads();
    double total = shared[32];
    __syncthreads();   // shared may be reused by the next call
    return total;
}

// One block per (n, g): the group's Cg * HW values are consecutive in NCHW.
__global__ void __launch_bounds__(GN_THREADS) groupnorm_kernel(float* out, float* mean, float* rstd, const float* in,
                                                               const float* weight, const float* bias, int C, int HW,
                                                               int G, float eps, mlb_activation act) {
    __shared__ double red[33];
    const int ng = blockIdx.x, g = ng % G, Cg = C / G;
    const size_t M = (size_t)Cg * HW;
    const float* x = in + (size_t)ng * M;
    float* o = out + (size_t)ng * M;
    double m = 0, v = 0;
    for (size_t i = threadIdx.x; i < M; i += blockDim.x) m += (double)x[i];
    m = block_sum(m, red);
    m = M ? m / (double)M : 0;
    for (size_t i = threadIdx.x; i < M; i += blockDim.x) { double d = (double)x[i] - m; v += d * d; }
    v = block_sum(v, red);
    v = M ? v / (double)M : 0;
    double r = 1.0 / sqrt(v + (double)eps);
    for (size_t i = threadIdx.x; i < M; i += blockDim.x) {
        int c = g * Cg + (int)(i / HW);
        float w = weight ? weight[c] : 1.0f, b = bias ? bias[c] : 0.0f;
        float y = __fadd_rn(__fmul_rn((float)(((double)x[i] - m) * r), w), b);
        o[i] = dev_gn_act(act, y);
    }
    if (threadIdx.x == 0) {
        if (mean) mean[ng] = (float)m;
        if (rstd) rstd[ng] = (float)r;
    }
}

extern "C" mlb_status mlb_cuda_groupnorm_forward(float* out, float* mean, float* rstd, const float* in,
                                                 const float* weight, const float* bias, int N, int C, int HW, int G,
                                                 float eps, mlb_activation act) {
    if (N < 0 || C < 0 || HW < 0 || G <= 0 || C % G != 0)
        return mlb_fail(MLB_ERR_ARG, "mlb_cuda_groupnorm_forward: bad shape N %d C %d HW %d G %d (C must be a multiple of G)",
                        N, C, HW, G);
    if ((int)act < 0 || act >= MLB_ACT_COUNT) return mlb_fail(MLB_ERR_ARG, "mlb_cuda_groupnorm_forward: unknown activation %d", (int)act);
    if (N == 0 || C == 0) return MLB_OK;
    if ((size_t)N * G > 0x7fffffffu) return mlb_fail(MLB_ERR_ARG, "mlb_cuda_groupnorm_forward: N*G too large");
    groupnorm_kernel<<<(unsigned)(N * G), GN_THREADS>>>(out, mean, rstd, in, weight, bias, C, HW, G, eps, act);
    MLB_CUDA_LAUNCHED("groupnorm_kernel");
    return MLB_OK;
}

// ---- backward ----

// din rows: one warp per row, the sums of g and g * xhat in double (CPU: layernorm_backward).
__global__ void layernorm_backward_din_kernel(float* din, const float* dout, const float* in, const float* weight,
                                              const float* mean, const float* rstd, int N, int C) {
    int warp = (blockIdx.x * blockDim.x + threadIdx.x) >> 5, lane = threadIdx.x & 31;
    if (warp >= N) return;
    const float* x = in + (size_t)warp * C;
    const float* d = dout + (size_t)warp * C;
    float* dx = din + (size_t)warp * C;
    const float m = mean[warp], r = rstd[warp];
    double sg = 0, sgx = 0;
    for (int c = lane; c < C; c += 32) {
        float xh = (x[c] - m) * r, g = d[c] * (weight ? weight[c] : 1.0f);
        sg += (double)g;
        sgx += (double)g * (double)xh;
    }
    sg = warp_sum(sg);
    sgx = warp_sum(sgx);
    const float mg = (float)(sg / C), mgx = (float)(sgx / C);
    for (int c = lane; c < C; c += 32) {
        float xh = (x[c] - m) * r, g = d[c] * (weight ? weight[c] : 1.0f);
        dx[c] += r * (g - mg - xh * mgx);
    }
}

// dweight/dbias: one thread per column, rows in order, in double (deterministic, coalesced).
__global__ void layernorm_backward_dwb_kernel(float* dweight, float* dbias, const float* dout, const float* in,
                                              const float* mean, const float* rstd, int N, int C) {
    int c = blockIdx.x * blockDim.x + threadIdx.x;
    if (c >= C) return;
    double aw = 0, ab = 0;
    for (int n = 0; n < N; n++) {
        float d = dout[(size_t)n * C + c];
        aw += (double)d * (double)((in[(size_t)n * C + c] - mean[n]) * rstd[n]);
        ab += (double)d;
    }
    if (dweight) dweight[c] += (float)aw;
    if (dbias) dbias[c] += (float)ab;
}

extern "C" mlb_status mlb_cuda_layernorm_backward(float* din, float* dweight, float* dbias, const float* dout,
                                                  const float* in, const float* weight, const float* mean,
                                                  const float* rstd, int N, int C) {
    if (N < 0 || C < 0) return mlb_fail(MLB_ERR_ARG, "mlb_cuda_layernorm_backward: bad shape N %d C %d", N, C);
    if (N == 0 || C == 0) return MLB_OK;
    if (din) {
        layernorm_backward_din_kernel<<<mlb_blocks(N, 8), 256>>>(din, dout, in, weight, mean, rstd, N, C);
        MLB_CUDA_LAUNCHED("layernorm_backward_din_kernel");
    }
    if (dweight || dbias) {
        layernorm_backward_dwb_kernel<<<mlb_blocks(C, 128), 128>>>(dweight, dbias, dout, in, mean, rstd, N, C);
        MLB_CUDA_LAUNCHED("layernorm_backward_dwb_kernel");
    }
    return MLB_OK;
}

__device__ __forceinline__ float dev_gn_act_d1(mlb_activation act, float y) {
    if (act == MLB_ACT_IDENTITY) return 1.0f;
    if (act == MLB_ACT_SILU) {
        float e = expf(-fabsf(y));
        float sg = y >= 0 ? 1.0f / (1.0f + e) : e / (1.0f + e);
        return sg * (1.0f + y * (1.0f - sg));
    }
    return dev_act_d1(act, y);
}

// One block per (n, g) (CPU: groupnorm_backward): per channel the sums of gy * xhat and gy (kept in
// part [N, C, 2] for dweight/dbias), then din.
__global__ void __launch_bounds__(GN_THREADS) groupnorm_backward_kernel(float* din, double* part, const float* dout,
                                                                        const float* in, const float* weight,
                                                                        const float* bias, const float* mean,
                                                                        const float* rstd, int C, int HW, int G,
                                                                        mlb_activation act) {
    __shared__ double red[33];
    const int ng = blockIdx.x, g = ng % G, n = ng / G, Cg = C / G;
    const size_t M = (size_t)Cg * HW;
    const float* x = in + (size_t)ng * M;
    const float* d = dout + (size_t)ng * M;
    const float m = mean[ng], r = rstd[ng];
    double s1 = 0, s2 = 0;
    for (int cc = 0; cc < Cg; cc++) {
        const int c = g * Cg + cc;
        const float w = weight ? weight[c] : 1.0f, b = bias ? bias[c] : 0.0f;
        double pw = 0, pb = 0;
        for (int p = threadIdx.x; p < HW; p += blockDim.x) {
            size_t i = (size_t)cc * HW + p;
            float xh = (x[i] - m) * r;
            float gy = d[i] * dev_gn_act_d1(act, xh * w + b);
            pw += (double)gy * (double)xh;
            pb += (double)gy;
        }
        pw = block_sum(pw, red);
        pb = block_sum(pb, red);
        s1 += pb * (double)w;
        s2 += pw * (double)w;
        if (part && threadIdx.x == 0) {
            part[((size_t)n * C + c) * 2] = pw;
            part[((size_t)n * C + c) * 2 + 1] = pb;
        }
    }
    if (!din) return;
    const float mg = (float)(M ? s1 / (double)M : 0), mgx = (float)(M ? s2 / (double)M : 0);
    float* dx = din + (size_t)ng * M;
    for (size_t i = threadIdx.x; i < M; i += blockDim.x) {
        const int c = g * Cg + (int)(i / HW);
        const float w = weight ? weight[c] : 1.0f, b = bias ? bias[c] : 0.0f;
        float xh = (x[i] - m) * r;
        float gy = d[i] * dev_gn_act_d1(act, xh * w + b);
        dx[i] += r * (gy * w - mg - xh * mgx);
    }
}

// dweight[c], dbias[c] += sums over n in order of part (deterministic).
__global__ void groupnorm_backward_dwb_kernel(float* dweight, float* dbias, const double* part, int N, int C) {
    int c = blockIdx.x * blockDim.x + threadIdx.x;
    if (c >= C) return;
    double sw = 0, sb = 0;
    for (int n = 0; n < N; n++) {
        sw += part[((size_t)n * C + c) * 2];
        sb += part[((size_t)n * C + c) * 2 + 1];
    }
    if (dweight) dweight[c] += (float)sw;
    if (dbias) dbias[c] += (float)sb;
}

extern "C" mlb_status mlb_cuda_groupnorm_backward(float* din, float* dweight, float* dbias, const float* dout,
                                                  const float* in, const float* weight, const float* bias,
                                                  const float* mean, const float* rstd, int N, int C, int HW, int G,
                                                  mlb_activation act) {
    if (N < 0 || C < 0 || HW < 0 || G <= 0 || C % G != 0)
        return mlb_fail(MLB_ERR_ARG, "mlb_cuda_groupnorm_backward: bad shape N %d C %d HW %d G %d (C must be a multiple of G)",
                        N, C, HW, G);
    if ((int)act < 0 || act >= MLB_ACT_COUNT) return mlb_fail(MLB_ERR_ARG, "mlb_cuda_groupnorm_backward: unknown activation %d", (int)act);
    if (N == 0 || C == 0 || (!din && !dweight && !dbias)) return MLB_OK;
    if ((size_t)N * G > 0x7fffffffu) return mlb_fail(MLB_ERR_ARG, "mlb_cuda_groupnorm_backward: N*G too large");
    double* part = NULL;
    if (dweight || dbias) MLB_TRY(mlb_cuda_scratch((void**)&part, (size_t)N * C * 2 * sizeof(double)));
    groupnorm_backward_kernel<<<(unsigned)(N * G), GN_THREADS>>>(din, part, dout, in, weight, bias, mean, rstd, C, HW, G, act);
    MLB_CUDA_LAUNCHED("groupnorm_backward_kernel");
    if (part) {
        groupnorm_backward_dwb_kernel<<<mlb_blocks(C, 128), 128>>>(dweight, dbias, part, N, C);
        MLB_CUDA_LAUNCHED("groupnorm_backward_dwb_kernel");
    }
    return MLB_OK;
}
