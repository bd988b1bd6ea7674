// Convolution and scaled dot-product attention on the device as GEMMs on the tensor cores:
//   conv2d: im2col of a chunk of images ([nb][C*KH*KW][OH*OW], in the GEMM's operand type, so the
//           fp16/bf16 conversion is free) and one strided batched GEMM with the weight reused
//           (stride 0); a 1x1 stride-1 unpadded conv in fp32/tf32 is the GEMM alone.
//   sdpa:   q, k, v split into heads [B, NH, T, hd] (converted on the way), scores S = q k^T / sqrt(hd)
//           as one batched GEMM over (image, head) for a chunk of images, a row softmax (a warp per
//           row) and O = P v, merged back to [B, Tq, C]. At fp16/bf16 with heads up to 128 wide
//           the fused kernel of flash_attention.cu runs instead (the scores stay in registers).
// The contracts of conv2d_forward and sdpa_forward (conv_ops.h). Scratch chunks stay under
// CHUNK_BYTES whatever the batch: the scores of SD's 64^2 latent (8 heads, 4096^2) are 512 MiB per
// image.
#include <cuda_bf16.h>
#include <cuda_fp16.h>
#include <math.h>
#include "common.cuh"
extern "C" {
#include "matlaber/conv_ops.h"
}

#include "conv_cudnn.cuh"
#include "gemm_ops.cuh"

// out[row, i] = bias[row % OC] for rows = N*OC planes of HW values
__global__ void fill_channel_kernel(float* out, const float* bias, size_t rows, int OC, int HW) {
    size_t n = rows * (size_t)HW;
    for (size_t i = (size_t)blockIdx.x * blockDim.x + threadIdx.x; i < n; i += (size_t)gridDim.x * blockDim.x)
        out[i] = bias[(i / HW) % OC];
}

template <typename T>
static mlb_status launch_im2col(void* cols, const float* in, int nb, const conv_geom& g) {
    size_t n = (size_t)nb * g.C * g.KH * g.KW * g.OH * g.OW;
    im2col_kernel<T><<<mlb_grid(n, 256), 256>>>((T*)cols, in, nb, g);
    MLB_CUDA_LAUNCHED("im2col_kernel");
    return MLB_OK;
}
mlb_status mlb_cuda_im2col(mlb_cuda_dtype dt, void* cols, const float* in, int nb, const conv_geom& g) {
    if (dt == MLB_DTYPE_F16) return launch_im2col<__half>(cols, in, nb, g);
    if (dt == MLB_DTYPE_BF16) return launch_im2col<__nv_bfloat16>(cols, in, nb, g);
    return launch_im2col<float>(cols, in, nb, g);
}

extern "C" mlb_status mlb_cuda_conv2d_forward(float* out, const float* in, const float* weight, const float* bias,
                                              const mlb_conv2d* cv, mlb_gemm_precision prec) {
    if (!out || !in || !weight || !cv) return mlb_fail(MLB_ERR_ARG, "mlb_cuda_conv2d_forward: NULL argument");
    MLB_TRY(mlb_conv2d_check(cv));
    if (mlb_cudnn_conv_usable(cv)) return mlb_cudnn_conv2d_forward(out, in, weight, bias, cv, prec);
    conv_geom g = conv_geom_of(cv);
    const int N = cv->N, OC = cv->OC, OHW = g.OH * g.OW, CKK = g.C * g.KH * g.KW;
    float beta = 0.0f;
    if (bias) {
        fill_channel_kernel<<<mlb_grid((size_t)N * OC * OHW, 256), 256>>>(out, bias, (size_t)N * OC, OC, OHW);
        MLB_CUDA_LAUNCHED("fill_channel_kernel");
        beta = 1.0f;
    }
    const int half = is_half(prec);
    if (!half && g.KH == 1 && g.KW == 1 && g.sh == 1 && g.sw == 1 && !g.pt && !g.pl && !cv->pad_bottom &&
        !cv->pad_right)   // out_n [OC, HW] = W [OC, C] in_n [C, HW]
        return mlb_cuda_gemm_batched(0, 0, OC, OHW, g.C, 1.0f, weight, g.C, 0, in, OHW, (long long)g.C * OHW, beta,
                                     out, OHW, (long long)OC * OHW, N, MLB_DTYPE_F32, prec);
    const size_t esz = half ? 2 : 4, per_image = (size_t)CKK * OHW * esz;
    size_t nb = CHUNK_BYTES / per_image;
    if (nb < 1) nb = 1;
    if (nb > (size_t)N) nb = (size_t)N;
    const size_t w_bytes = half ? round_up((size_t)OC * CKK * esz) : 0;
    void* s;
    MLB_TRY(mlb_cuda_scratch(&s, w_bytes + nb * per_image));
    const mlb_cuda_dtype dt = operand_type(prec);
    const void* w_op = weight;
    if (half) {
        MLB_TRY(mlb_cuda_convert(s, dt, weight, (size_t)OC * CKK));
        w_op = s;
    }
    void* cols = (char*)s + w_bytes;
    for (int n0 = 0; n0 < N; n0 += (int)nb) {
        int m = N - n0 < (int)nb ? N - n0 : (int)nb;
        const float* src = in + (size_t)n0 * g.C * g.H * g.W;
        MLB_TRY(mlb_cuda_im2col(dt, cols, src, m, g));
        MLB_TRY(mlb_cuda_gemm_batched(0, 0, OC, OHW, CKK, 1.0f, w_op, CKK, 0, cols, OHW, (long long)CKK * OHW, beta,
                                      out + (size_t)n0 * OC * OHW, OHW, (long long)OC * OHW, m, dt, prec));
    }
    return MLB_OK;
}

// ---- scaled dot-product attention ----------------------------------------------------------------
// out[((b*NH + h)*T + t)*hd + e] = in[(b*T + t)*ld + h*hd + e]
template <typename T>
__global__ void split_heads_kernel(T* out, const float* in, int B, int T_, int NH, int hd, int ld) {
    size_t n = (size_t)B * NH * T_ * hd;
    for (size_t i = (size_t)blockIdx.x * blockDim.x + threadIdx.x; i < n; i += (size_t)gridDim.x * blockDim.x) {
        size_t e = i % hd, r = i / hd, t = r % T_, bh = r / T_, h = bh % NH, b = bh / NH;
        out[i] = to_operand<T>(in[(b * T_ + t) * ld + h * hd + e]);
    }
}

// out[(b*T + t)*C + h*hd + e] = o[((b*NH + h)*T + t)*hd + e], C = NH hd
__global__ void merge_heads_kernel(float* out, const float* o, int B, int T_, int NH, int hd) {
    size_t n = (size_t)B * NH * T_ * hd;
    const int C = NH * hd;
    for (size_t i = (size_t)blockIdx.x * blockDim.x + threadIdx.x; i < n; i += (size_t)gridDim.x * blockDim.x) {
        size_t e = i % C, bt = i / C, h = e / hd, b = bt / T_, t = bt % T_;
        out[i] = o[((b * NH + h) * T_ + t) * hd + e % hd];
    }
}

// p[row] = softmax(s[row]) over Tk columns, a warp per row: max, sum of exp, then the quotient;
// lse[row] = max + log(sum) when lse is not NULL. p may alias s when T is float.
template <typename T>
__global__ void softmax_rows_kernel(T* p, float* lse, const float* s, size_t rows, int Tk) {
    size_t row = ((size_t)blockIdx.x * blockDim.x + threadIdx.x) >> 5;
    const int lane = threadIdx.x & 31;
    if (row >= rows) return;
    const float* sr = s + row * Tk;
    float m = -INFINITY;
    for (int j = lane; j < Tk; j += 32) m = fmaxf(m, sr[j]);
    for (int o = 16; o; o >>= 1) m = fmaxf(m, __shfl_xor_sync(0xffffffffu, m, o));
    float sum = 0.0f;
    for (int j = lane; j < Tk; j += 32) sum += expf(sr[j] - m);
    for (int o = 16; o; o >>= 1) sum += __shfl_xor_sync(0xffffffffu, sum, o);
    const float inv = 1.0f / sum;
    if (lse && lane == 0) lse[row] = m + logf(sum);
    T* pr = p + row * Tk;
    for (int j = lane; j < Tk; j += 32) pr[j] = to_operand<T>(expf(sr[j] - m) * inv);
}

template <typename T>
static mlb_status launch_split(void* out, const float* in, int B, int T_, int NH, int hd, int ld) {
    size_t n = (size_t)B * NH * T_ * hd;
    split_heads_kernel<T><<<mlb_grid(n, 256), 256>>>((T*)out, in, B, T_, NH, hd, ld);
    MLB_CUDA_LAUNCHED("split_heads_kernel");
    return MLB_OK;
}
template <typename T>
static mlb_status launch_softmax(void* p, float* lse, const float* s, size_t rows, int Tk) {
    softmax_rows_kernel<T><<<mlb_blocks(rows * 32, 256), 256>>>((T*)p, lse, s, rows, Tk);
    MLB_CUDA_LAUNCHED("softmax_rows_kernel");
    return MLB_OK;
}
mlb_status mlb_cuda_split_heads(mlb_cuda_dtype dt, void* out, const float* in, int B, int T_, int NH, int hd, int ld) {
    if (dt == MLB_DTYPE_F16) return launch_split<__half>(out, in, B, T_, NH, hd, ld);
    if (dt == MLB_DTYPE_BF16) return launch_split<__nv_bfloat16>(out, in, B, T_, NH, hd, ld);
    return launch_split<float>(out, in, B, T_, NH, hd, ld);
}

extern "C" mlb_status mlb_cuda_sdpa_forward(float* out, float* lse, const float* q, const float* k, const float* v, int B,
                                            int Tq, int Tk, int C, int NH, int ldq, int ldkv, mlb_gemm_precision prec) {
    if (!out || !q || !k || !v) return mlb_fail(MLB_ERR_ARG, "mlb_cuda_sdpa_forward: NULL argument");
    if (B < 0 || Tq < 0 || Tk < 1 || NH < 1 || C < NH || C % NH || ldq < C || ldkv < C)
        return mlb_fail(MLB_ERR_ARG, "mlb_cuda_sdpa_forward: bad shape B %d Tq %d Tk %d C %d heads %d ldq %d ldkv %d", B,
                        Tq, Tk, C, NH, ldq, ldkv);
    if (!B || !Tq) return MLB_OK;
    const int hd = C / NH;
    if (mlb_cuda_flash_usable(B, Tq, hd, NH, prec))
        return mlb_cuda_flash_sdpa(out, lse, q, k, v, B, Tq, Tk, C, NH, ldq, ldkv, prec);
    const mlb_cuda_dtype dt = operand_type(prec);
    const size_t esz = is_half(prec) ? 2 : 4, bh_scores = (size_t)NH * Tq * Tk;
    size_t nb = CHUNK_BYTES / (bh_scores * 4);
    if (nb < 1) nb = 1;
    if (nb > (size_t)B) nb = (size_t)B;
    const size_t q_bytes = round_up((size_t)B * Tq * C * esz), kv_bytes = round_up((size_t)B * Tk * C * esz);
    const size_t o_bytes = round_up((size_t)B * Tq * C * 4), s_bytes = round_up(nb * bh_scores * 4);
    const size_t p_bytes = esz == 4 ? 0 : round_up(nb * bh_scores * esz);
    void* base;
    MLB_TRY(mlb_cuda_scratch(&base, q_bytes + 2 * kv_bytes + o_bytes + s_bytes + p_bytes));
    char* qh = (char*)base;
    char* kh = qh + q_bytes;
    char* vh = kh + kv_bytes;
    float* o = (float*)(vh + kv_bytes);
    float* s = (float*)((char*)o + o_bytes);
    void* p = esz == 4 ? (void*)s : (void*)((char*)s + s_bytes);
    MLB_TRY(mlb_cuda_split_heads(dt, qh, q, B, Tq, NH, hd, ldq));
    MLB_TRY(mlb_cuda_split_heads(dt, kh, k, B, Tk, NH, hd, ldkv));
    MLB_TRY(mlb_cuda_split_heads(dt, vh, v, B, Tk, NH, hd, ldkv));
    const float scale = 1.0f / sqrtf((float)hd);
    for (int b0 = 0; b0 < B; b0 += (int)nb) {
        int m = B - b0 < (int)nb ? B - b0 : (int)nb, batch = m * NH;
        const char* qb = qh + (size_t)b0 * Tq * C * esz;
        const char* kb = kh + (size_t)b0 * Tk * C * esz;
        const char* vb = vh + (size_t)b0 * Tk * C * esz;
        // S[i] [Tq, Tk] = scale q_i [Tq, hd] k_i^T
        MLB_TRY(mlb_cuda_gemm_batched(0, 1, Tq, Tk, hd, scale, qb, hd, (long long)Tq * hd, kb, hd, (long long)Tk * hd,
                                      0.0f, s, Tk, (long long)Tq * Tk, batch, dt, prec));
        size_t rows = (size_t)batch * Tq;
        float* lse_b = lse ? lse + (size_t)b0 * NH * Tq : NULL;   // [B, NH, Tq], the CPU's layout
        if (dt == MLB_DTYPE_F16) MLB_TRY(launch_softmax<__half>(p, lse_b, s, rows, Tk));
        else if (dt == MLB_DTYPE_BF16) MLB_TRY(launch_softmax<__nv_bfloat16>(p, lse_b, s, rows, Tk));
        else MLB_TRY(launch_softmax<float>(p, lse_b, s, rows, Tk));
        // O_i [Tq, hd] = P_i [Tq, Tk] v_i [Tk, hd]
        MLB_TRY(mlb_cuda_gemm_batched(0, 0, Tq, hd, Tk, 1.0f, p, Tk, (long long)Tq * Tk, vb, hd, (long long)Tk * hd,
                                      0.0f, o + (size_t)b0 * Tq * C, hd, (long long)Tq * hd, batch, dt, prec));
    }
    size_t n = (size_t)B * Tq * C;
    merge_heads_kernel<<<mlb_grid(n, 256), 256>>>(out, o, B, Tq, NH, hd);
    MLB_CUDA_LAUNCHED("merge_heads_kernel");
    return MLB_OK;
}
