// The backward of conv2d and of attention on the device, as GEMMs on the tensor cores (the VAE
// encoder's backward for RGB-space SDS needs both). The contracts of conv2d_backward and
// sdpa_backward (conv_ops.h): every gradient ACCUMULATES (+=), any may be NULL.
//   conv2d: din: dcols_n [CKK, OHW] = W^T dout_n (one batched GEMM per chunk of images), then col2im
//           gathers each input value's contributions (a thread per value: no atomics, deterministic);
//           dweight += dout_n cols_n^T image by image (beta = 1); dbias: a block per channel, double.
//   sdpa:   the probabilities are recomputed from the forward's lse (P = exp(S - lse)); with
//           D = rowsum(dO o O): dP = dO V^T, dS = P o (dP - D), dQ = scale dS K, dK = scale dS^T Q,
//           dV = P^T dO, per chunk of images as batched GEMMs over (image, head).
#include <math.h>
#include "conv_cudnn.cuh"
#include "gemm_ops.cuh"

// ---- conv2d ------------------------------------------------------------------------------------
// din[b, c, iy, ix] += sum over (ki, kj) of dcols[b][(c*KH + ki)*KW + kj][oy*OW + ox] where
// iy = oy*sh - pt + ki and ix = ox*sw - pl + kj.
__global__ void col2im_acc_kernel(float* din, const float* dcols, int nb, conv_geom g) {
    const size_t HW = (size_t)g.H * g.W, n = (size_t)nb * g.C * HW, OHW = (size_t)g.OH * g.OW;
    const size_t CKK = (size_t)g.C * g.KH * g.KW;
    for (size_t i = (size_t)blockIdx.x * blockDim.x + threadIdx.x; i < n; i += (size_t)gridDim.x * blockDim.x) {
        size_t p = i % HW, bc = i / HW, c = bc % g.C, b = bc / g.C;
        int iy = (int)(p / g.W), ix = (int)(p % g.W);
        float sum = 0.0f;
        for (int ki = 0; ki < g.KH; ki++) {
            int ty = iy + g.pt - ki;
            if (ty < 0 || ty % g.sh) continue;
            int oy = ty / g.sh;
            if (oy >= g.OH) continue;
            for (int kj = 0; kj < g.KW; kj++) {
                int tx = ix + g.pl - kj;
                if (tx < 0 || tx % g.sw) continue;
                int ox = tx / g.sw;
                if (ox >= g.OW) continue;
                sum += dcols[(b * CKK + (c * g.KH + ki) * g.KW + kj) * OHW + (size_t)oy * g.OW + ox];
            }
        }
        din[i] += sum;
    }
}

// dbias[o] += sum over n, p of dout[n, o, p]: a block per channel, partial sums in double, a fixed tree.
__global__ void conv_dbias_kernel(float* dbias, const float* dout, int N, int OC, int OHW) {
    __shared__ double part[256];
    const int o = blockIdx.x;
    double s = 0;
    for (int n = 0; n < N; n++) {
        const float* d = dout + ((size_t)n * OC + o) * OHW;
        for (int p = threadIdx.x; p < OHW; p += blockDim.x) s += d[p];
    }
    part[threadIdx.x] = s;
    __syncthreads();
    for (int w = blockDim.x / 2; w > 0; w >>= 1) {
        if (threadIdx.x < w) part[threadIdx.x] += part[threadIdx.x + w];
        __syncthreads();
    }
    if (threadIdx.x == 0) dbias[o] += (float)part[0];
}

extern "C" mlb_status mlb_cuda_conv2d_backward(float* din, float* dweight, float* dbias, const float* dout,
                                               const float* in, const float* weight, const mlb_conv2d* cv,
                                               mlb_gemm_precision prec) {
    if (!dout || !cv || (din && !weight) || (dweight && !in))
        return mlb_fail(MLB_ERR_ARG, "mlb_cuda_conv2d_backward: NULL argument");
    MLB_TRY(mlb_conv2d_check(cv));
    const conv_geom g = conv_geom_of(cv);
    const int N = cv->N, OC = cv->OC, OHW = g.OH * g.OW, CKK = g.C * g.KH * g.KW;
    if (dbias) {
        conv_dbias_kernel<<<OC, 256>>>(dbias, dout, N, OC, OHW);
        MLB_CUDA_LAUNCHED("conv_dbias_kernel");
    }
    if (din && mlb_cudnn_conv_usable(cv)) {   // the input gradient by cuDNN, the weight gradient below
        MLB_TRY(mlb_cudnn_conv2d_backward_data(din, dout, weight, cv, prec));
        din = NULL;
    }
    if (!din && !dweight) return MLB_OK;
    const int half = is_half(prec);
    const mlb_cuda_dtype dt = operand_type(prec);
    const size_t esz = half ? 2 : 4;
    // per image: dcols (float) for din, cols (dt) for dweight, dout in dt when half
    const size_t per_image = (din ? (size_t)CKK * OHW * 4 : 0) + (dweight ? (size_t)CKK * OHW * esz : 0) +
                             (half ? (size_t)OC * OHW * esz : 0);
    size_t nb = CHUNK_BYTES / per_image;
    if (nb < 1) nb = 1;
    if (nb > (size_t)N) nb = (size_t)N;
    const size_t w_bytes = half ? round_up((size_t)OC * CKK * esz) : 0;
    const size_t dcols_bytes = din ? round_up(nb * CKK * OHW * 4) : 0, cols_bytes = dweight ? round_up(nb * CKK * OHW * esz) : 0;
    const size_t dout16_bytes = half ? round_up(nb * OC * OHW * esz) : 0;
    void* s;
    MLB_TRY(mlb_cuda_scratch(&s, w_bytes + dcols_bytes + cols_bytes + dout16_bytes));
    char* w16 = (char*)s;
    float* dcols = (float*)(w16 + w_bytes);
    char* cols = (char*)dcols + dcols_bytes;
    char* dout16 = cols + cols_bytes;
    const void* w_op = weight;
    if (half && din) {
        MLB_TRY(mlb_cuda_convert(w16, dt, weight, (size_t)OC * CKK));
        w_op = w16;
    }
    for (int n0 = 0; n0 < N; n0 += (int)nb) {
        const int m = N - n0 < (int)nb ? N - n0 : (int)nb;
        const float* dout_f = dout + (size_t)n0 * OC * OHW;
        const void* dout_op = dout_f;
        if (half) {
            MLB_TRY(mlb_cuda_convert(dout16, dt, dout_f, (size_t)m * OC * OHW));
            dout_op = dout16;
        }
        if (din) {
            // dcols_i [CKK, OHW] = W^T [CKK, OC] dout_i [OC, OHW]
            MLB_TRY(mlb_cuda_gemm_batched(1, 0, CKK, OHW, OC, 1.0f, w_op, CKK, 0, dout_op, OHW, (long long)OC * OHW,
                                          0.0f, dcols, OHW, (long long)CKK * OHW, m, dt, prec));
            size_t n = (size_t)m * g.C * g.H * g.W;
            col2im_acc_kernel<<<mlb_grid(n, 256), 256>>>(din + (size_t)n0 * g.C * g.H * g.W, dcols, m, g);
            MLB_CUDA_LAUNCHED("col2im_acc_kernel");
        }
        if (dweight) {
            MLB_TRY(mlb_cuda_im2col(dt, cols, in + (size_t)n0 * g.C * g.H * g.W, m, g));
            for (int i = 0; i < m; i++)   // dW [OC, CKK] += dout_i [OC, OHW] cols_i^T, images in order
                MLB_TRY(mlb_cuda_gemm(0, 1, OC, CKK, OHW, 1.0f, (const char*)dout_op + (size_t)i * OC * OHW * esz, OHW,
                                      cols + (size_t)i * CKK * OHW * esz, OHW, 1.0f, dweight, CKK, dt, prec));
        }
    }
    return MLB_OK;
}

// ---- attention -----------------------------------------------------------------------------------
// d[(b*NH + h)*T + t] = sum_e dout[b, t, h*hd + e] * out[b, t, h*hd + e]
__global__ void rowdot_kernel(float* d, const float* dout, const float* out, int B, int T_, int NH, int hd) {
    size_t rows = (size_t)B * NH * T_;
    for (size_t r = (size_t)blockIdx.x * blockDim.x + threadIdx.x; r < rows; r += (size_t)gridDim.x * blockDim.x) {
        size_t t = r % T_, bh = r / T_, h = bh % NH, b = bh / NH;
        const size_t base = (b * T_ + t) * (size_t)NH * hd + h * hd;
        float s = 0.0f;
        for (int e = 0; e < hd; e++) s += dout[base + e] * out[base + e];
        d[r] = s;
    }
}

// p = exp(s - lse[row]) in place (float), and its operand copy when p16 is not NULL
template <typename T>
__global__ void probs_kernel(float* p, T* p16, const float* lse, size_t rows, int Tk) {
    size_t n = rows * (size_t)Tk;
    for (size_t i = (size_t)blockIdx.x * blockDim.x + threadIdx.x; i < n; i += (size_t)gridDim.x * blockDim.x) {
        float v = expf(p[i] - lse[i / Tk]);
        p[i] = v;
        if (p16) p16[i] = to_operand<T>(v);
    }
}

// ds = p * (dp - d[row]) into dp's place, and its operand copy when ds16 is not NULL
template <typename T>
__global__ void dscores_kernel(float* dp, T* ds16, const float* p, const float* d, size_t rows, int Tk) {
    size_t n = rows * (size_t)Tk;
    for (size_t i = (size_t)blockIdx.x * blockDim.x + threadIdx.x; i < n; i += (size_t)gridDim.x * blockDim.x) {
        float v = p[i] * (dp[i] - d[i / Tk]);
        dp[i] = v;
        if (ds16) ds16[i] = to_operand<T>(v);
    }
}

// out[(b*T + t)*ld + h*hd + e] += o[((b*NH + h)*T + t)*hd + e]
__global__ void merge_heads_acc_kernel(float* out, const float* o, int B, int T_, int NH, int hd, int ld) {
    size_t n = (size_t)B * NH * T_ * hd;
    for (size_t i = (size_t)blockIdx.x * blockDim.x + threadIdx.x; i < n; i += (size_t)gridDim.x * blockDim.x) {
        size_t e = i % hd, r = i / hd, t = r % T_, bh = r / T_, h = bh % NH, b = bh / NH;
        out[(b * T_ + t) * ld + h * hd + e] += o[i];
    }
}

template <typename T>
static mlb_status launch_probs(float* p, void* p16, const float* lse, size_t rows, int Tk) {
    probs_kernel<T><<<mlb_grid(rows * Tk, 256), 256>>>(p, (T*)p16, lse, rows, Tk);
    MLB_CUDA_LAUNCHED("probs_kernel");
    return MLB_OK;
}
template <typename T>
static mlb_status launch_dscores(float* dp, void* ds16, const float* p, const float* d, size_t rows, int Tk) {
    dscores_kernel<T><<<mlb_grid(rows * Tk, 256), 256>>>(dp, (T*)ds16, p, d, rows, Tk);
    MLB_CUDA_LAUNCHED("dscores_kernel");
    return MLB_OK;
}
static mlb_status merge_acc(float* out, const float* o, int B, int T_, int NH, int hd, int ld) {
    if (!out) return MLB_OK;
    size_t n = (size_t)B * NH * T_ * hd;
    merge_heads_acc_kernel<<<mlb_grid(n, 256), 256>>>(out, o, B, T_, NH, hd, ld);
    MLB_CUDA_LAUNCHED("merge_heads_acc_kernel");
    return MLB_OK;
}

extern "C" mlb_status mlb_cuda_sdpa_backward(float* dq, float* dk, float* dv, const float* dout, const float* out,
                                             const float* lse, const float* q, const float* k, const float* v, int B,
                                             int Tq, int Tk, int C, int NH, int ldq, int ldkv,
                                             mlb_gemm_precision prec) {
    if (!dout || !out || !lse || !q || !k || !v) return mlb_fail(MLB_ERR_ARG, "mlb_cuda_sdpa_backward: NULL argument");
    if (B < 0 || Tq < 0 || Tk < 1 || NH < 1 || C < NH || C % NH || ldq < C || ldkv < C)
        return mlb_fail(MLB_ERR_ARG, "mlb_cuda_sdpa_backward: bad shape B %d Tq %d Tk %d C %d heads %d ldq %d ldkv %d",
                        B, Tq, Tk, C, NH, ldq, ldkv);
    if (!B || !Tq || (!dq && !dk && !dv)) return MLB_OK;
    const int hd = C / NH, half = is_half(prec);
    const mlb_cuda_dtype dt = operand_type(prec);
    const size_t esz = half ? 2 : 4, bh_scores = (size_t)NH * Tq * Tk;
    size_t nb = CHUNK_BYTES / (bh_scores * (8 + (half ? 2 * esz : 0)));
    if (nb < 1) nb = 1;
    if (nb > (size_t)B) nb = (size_t)B;
    const size_t q_op = round_up((size_t)B * Tq * C * esz), kv_op = round_up((size_t)B * Tk * C * esz);
    const size_t q_f = round_up((size_t)B * Tq * C * 4), kv_f = round_up((size_t)B * Tk * C * 4);
    const size_t d_bytes = round_up((size_t)B * NH * Tq * 4), sc = round_up(nb * bh_scores * 4);
    const size_t sc16 = half ? round_up(nb * bh_scores * esz) : 0;
    void* base;
    MLB_TRY(mlb_cuda_scratch(&base, 2 * q_op + 2 * kv_op + q_f + 2 * kv_f + d_bytes + 2 * sc + 2 * sc16));
    char* c = (char*)base;
    char *qh = c, *doh = qh + q_op, *kh = doh + q_op, *vh = kh + kv_op;
    float* dqh = (float*)(vh + kv_op);
    float* dkh = (float*)((char*)dqh + q_f);
    float* dvh = (float*)((char*)dkh + kv_f);
    float* d = (float*)((char*)dvh + kv_f);
    float* p = (float*)((char*)d + d_bytes);
    float* dp = (float*)((char*)p + sc);
    char* p16 = (char*)dp + sc;
    char* ds16 = p16 + sc16;
    const void* p_op = half ? (const void*)p16 : (const void*)p;
    const void* ds_op = half ? (const void*)ds16 : (const void*)dp;
    MLB_TRY(mlb_cuda_split_heads(dt, qh, q, B, Tq, NH, hd, ldq));
    MLB_TRY(mlb_cuda_split_heads(dt, doh, dout, B, Tq, NH, hd, C));
    MLB_TRY(mlb_cuda_split_heads(dt, kh, k, B, Tk, NH, hd, ldkv));
    MLB_TRY(mlb_cuda_split_heads(dt, vh, v, B, Tk, NH, hd, ldkv));
    size_t rows_all = (size_t)B * NH * Tq;
    rowdot_kernel<<<mlb_grid(rows_all, 256), 256>>>(d, dout, out, B, Tq, NH, hd);
    MLB_CUDA_LAUNCHED("rowdot_kernel");
    const float scale = 1.0f / sqrtf((float)hd);
    for (int b0 = 0; b0 < B; b0 += (int)nb) {
        const int m = B - b0 < (int)nb ? B - b0 : (int)nb, batch = m * NH;
        const size_t rows = (size_t)batch * Tq, qo = (size_t)b0 * Tq * C, ko = (size_t)b0 * Tk * C;
        const char *qb = qh + qo * esz, *dob = doh + qo * esz, *kb = kh + ko * esz, *vb = vh + ko * esz;
        const float *lse_b = lse + (size_t)b0 * NH * Tq, *d_b = d + (size_t)b0 * NH * Tq;
        // P = exp(scale q k^T - lse)
        MLB_TRY(mlb_cuda_gemm_batched(0, 1, Tq, Tk, hd, scale, qb, hd, (long long)Tq * hd, kb, hd, (long long)Tk * hd,
                                      0.0f, p, Tk, (long long)Tq * Tk, batch, dt, prec));
        if (dt == MLB_DTYPE_F16) MLB_TRY(launch_probs<__half>(p, p16, lse_b, rows, Tk));
        else if (dt == MLB_DTYPE_BF16) MLB_TRY(launch_probs<__nv_bfloat16>(p, p16, lse_b, rows, Tk));
        else MLB_TRY(launch_probs<float>(p, NULL, lse_b, rows, Tk));
        // dV = P^T dO
        MLB_TRY(mlb_cuda_gemm_batched(1, 0, Tk, hd, Tq, 1.0f, p_op, Tk, (long long)Tq * Tk, dob, hd, (long long)Tq * hd,
                                      0.0f, dvh + ko, hd, (long long)Tk * hd, batch, dt, prec));
        // dP = dO V^T, then dS = P o (dP - D)
        MLB_TRY(mlb_cuda_gemm_batched(0, 1, Tq, Tk, hd, 1.0f, dob, hd, (long long)Tq * hd, vb, hd, (long long)Tk * hd,
                                      0.0f, dp, Tk, (long long)Tq * Tk, batch, dt, prec));
        if (dt == MLB_DTYPE_F16) MLB_TRY(launch_dscores<__half>(dp, ds16, p, d_b, rows, Tk));
        else if (dt == MLB_DTYPE_BF16) MLB_TRY(launch_dscores<__nv_bfloat16>(dp, ds16, p, d_b, rows, Tk));
        else MLB_TRY(launch_dscores<float>(dp, NULL, p, d_b, rows, Tk));
        // dQ = scale dS K, dK = scale dS^T Q
        MLB_TRY(mlb_cuda_gemm_batched(0, 0, Tq, hd, Tk, scale, ds_op, Tk, (long long)Tq * Tk, kb, hd, (long long)Tk * hd,
                                      0.0f, dqh + qo, hd, (long long)Tq * hd, batch, dt, prec));
        MLB_TRY(mlb_cuda_gemm_batched(1, 0, Tk, hd, Tq, scale, ds_op, Tk, (long long)Tq * Tk, qb, hd, (long long)Tq * hd,
                                      0.0f, dkh + ko, hd, (long long)Tk * hd, batch, dt, prec));
    }
    MLB_TRY(merge_acc(dq, dqh, B, Tq, NH, hd, ldq));
    MLB_TRY(merge_acc(dk, dkh, B, Tk, NH, hd, ldkv));
    return merge_acc(dv, dvh, B, Tk, NH, hd, ldkv);
}
