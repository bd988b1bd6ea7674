// Convolution-family ops (conv_ops.h): conv2d by im2col over bands of output rows + GEMM, group
// norm with a fused activation, nearest 2x upsampling, batched transpose, and blocked scaled
// dot-product attention. Dual-compiled (float / double _f64) like the other MLB_DUAL_SOURCES.
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/conv_ops.h"
#include "matlaber/error.h"
#include "matlaber/nn.h"
#include "core/real.h"
#include "nn/simd_rows.h"
#ifndef MLB_F64
#include "nn/conv_bf16.h"
#endif

// Below this many values a loop stays on one thread (the fork/join costs more than the work).
#define COPS_PARALLEL_MIN 32768
// Target size (elements) of the im2col band and of an attention score block.
#define COPS_COL_BUDGET ((size_t)1 << 22)
#define COPS_ATT_BUDGET ((size_t)1 << 20)

// Whether a conv is a plain GEMM (1x1, stride 1, no padding), and output rows per im2col band.
static int FN(pointwise)(const mlb_conv2d* cv) {
    return cv->KH == 1 && cv->KW == 1 && cv->stride_h == 1 && cv->stride_w == 1 && cv->pad_top == 0 &&
           cv->pad_left == 0 && cv->pad_bottom == 0 && cv->pad_right == 0;
}

static int FN(band_rows)(const mlb_conv2d* cv) {
    int OH = mlb_conv2d_out_h(cv), OW = mlb_conv2d_out_w(cv);
    size_t per_row = (size_t)cv->C * cv->KH * cv->KW * (size_t)OW;
    size_t rows = per_row ? COPS_COL_BUDGET / per_row : 1;
    if (rows < 1) rows = 1;
    if (rows > (size_t)OH) rows = (size_t)OH;
    return (int)rows;
}

// Query rows per attention score block (Tq, Tk >= 1).
static size_t FN(att_rows)(int Tq, int Tk) {
    size_t rows = COPS_ATT_BUDGET / (size_t)Tk;
    if (rows < 16) rows = 16;
    if (rows > (size_t)Tq) rows = (size_t)Tq;
    return rows;
}

// ---- precision-independent functions (compiled once, in the float pass) --------------------------
#ifndef MLB_F64
size_t conv2d_workspace_size(const mlb_conv2d* cv) {
    if (!cv || mlb_conv2d_check(cv) != MLB_OK) { mlb_clear_error(); return 0; }
    if (pointwise(cv)) return 0;
    return (size_t)cv->C * cv->KH * cv->KW * (size_t)band_rows(cv) * (size_t)mlb_conv2d_out_w(cv);
}

size_t sdpa_workspace_size(int Tq, int Tk) {
    if (Tq < 1 || Tk < 1) return 0;
    return 2 * att_rows(Tq, Tk) * (size_t)Tk;
}
#endif

// ---- conv2d ----------------------------------------------------------------------------------------
// The valid output columns [*lo, *hi) for kernel column j: 0 <= x*sw - pl + j < W.
static inline void FN(valid_range)(int n_out, int stride, int pad, int j, int n_in, int* lo, int* hi) {
    int off = j - pad;   // input index = x * stride + off
    int a = off >= 0 ? 0 : (-off + stride - 1) / stride;
    int b = n_in - off <= 0 ? 0 : (n_in - 1 - off) / stride + 1;   // first x with x*stride + off >= n_in
    if (b > n_out) b = n_out;
    if (a > b) a = b;
    *lo = a;
    *hi = b;
}

// col[K, rows*OW] for output rows [y0, y0 + rows) of image `in` ([C, H, W]); K = C*KH*KW, row
// index (c*KH + i)*KW + j. Parallel over the K rows (each written by one thread).
static void FN(im2col)(real* col, const real* in, const mlb_conv2d* cv, int OW, int y0, int rows) {
    const int KH = cv->KH, KW = cv->KW, H = cv->H, W = cv->W, sh = cv->stride_h, sw = cv->stride_w;
    const int K = cv->C * KH * KW;
    const size_t P = (size_t)rows * OW;
#pragma omp parallel for schedule(static) if ((size_t)K * P >= COPS_PARALLEL_MIN)
    for (int r = 0; r < K; r++) {
        int c = r / (KH * KW), i = (r / KW) % KH, j = r % KW;
        int lo, hi;
        FN(valid_range)(OW, sw, cv->pad_left, j, W, &lo, &hi);
        const real* src = in + (size_t)c * H * W;
        real* dst = col + (size_t)r * P;
        for (int yy = 0; yy < rows; yy++) {
            int iy = (y0 + yy) * sh - cv->pad_top + i;
            real* d = dst + (size_t)yy * OW;
            if (iy < 0 || iy >= H) { memset(d, 0, (size_t)OW * sizeof(real)); continue; }
            const real* s = src + (size_t)iy * W;
            const int off = j - cv->pad_left;
            for (int x = 0; x < lo; x++) d[x] = 0;
            if (sw == 1 && hi > lo) memcpy(d + lo, s + lo + off, (size_t)(hi - lo) * sizeof(real));
            else for (int x = lo; x < hi; x++) d[x] = s[x * sw + off];
            for (int x = hi; x < OW; x++) d[x] = 0;
        }
    }
}

// din ([C, H, W]) += col2im(col) for output rows [y0, y0 + rows). Parallel over channels: the
// KH*KW rows of one channel are added by one thread in a fixed order.
static void FN(col2im_add)(real* din, const real* col, const mlb_conv2d* cv, int OW, int y0, int rows) {
    const int KH = cv->KH, KW = cv->KW, H = cv->H, W = cv->W, sh = cv->stride_h, sw = cv->stride_w;
    const size_t P = (size_t)rows * OW;
#pragma omp parallel for schedule(static) if ((size_t)cv->C * KH * KW * P >= COPS_PARALLEL_MIN)
    for (int c = 0; c < cv->C; c++) {
        real* dst = din + (size_t)c * H * W;
        for (int i = 0; i < KH; i++)
            for (int j = 0; j < KW; j++) {
                int lo, hi;
                FN(valid_range)(OW, sw, cv->pad_left, j, W, &lo, &hi);
                const real* src = col + ((size_t)(c * KH + i) * KW + j) * P;
                for (int yy = 0; yy < rows; yy++) {
                    int iy = (y0 + yy) * sh - cv->pad_top + i;
                    if (iy < 0 || iy >= H) continue;
                    real* d = dst + (size_t)iy * W;
                    const real* s = src + (size_t)yy * OW;
                    const int off = j - cv->pad_left;
                    for (int x = lo; x < hi; x++) d[x * sw + off] += s[x];
                }
            }
    }
}

static mlb_status FN(conv_ws)(real** ws, real** owned, const mlb_conv2d* cv) {
    *owned = NULL;
    if (*ws || FN(pointwise)(cv)) return MLB_OK;
    size_t n = (size_t)cv->C * cv->KH * cv->KW * (size_t)FN(band_rows)(cv) * (size_t)mlb_conv2d_out_w(cv);
    *owned = malloc(n * sizeof(real));
    if (!*owned)
        return mlb_fail(MLB_ERR_NOMEM, "conv2d: out of memory for a %zu-element workspace (%.1f MB)", n,
                        n * (double)sizeof(real) / 1e6);
    *ws = *owned;
    return MLB_OK;
}

static mlb_status FN(conv2d_forward_with)(FN(mlb_gemm_fn) gemm, real* out, const real* in, const real* weight,
                                          const real* bias, const mlb_conv2d* cv, real* ws) {
    MLB_TRY(mlb_conv2d_check(cv));
    if (!out || !in || !weight) return mlb_fail(MLB_ERR_ARG, "conv2d: NULL buffer");
    const int OH = mlb_conv2d_out_h(cv), OW = mlb_conv2d_out_w(cv), K = cv->C * cv->KH * cv->KW;
    const size_t in_n = (size_t)cv->C * cv->H * cv->W, out_n = (size_t)cv->OC * OH * OW, plane = (size_t)OH * OW;
    real* owned;
    MLB_TRY(FN(conv_ws)(&ws, &owned, cv));
    for (int n = 0; n < cv->N; n++) {
        real* o = out + (size_t)n * out_n;
#pragma omp parallel for schedule(static) if (out_n >= COPS_PARALLEL_MIN)
        for (int oc = 0; oc < cv->OC; oc++) {
            real b = bias ? bias[oc] : (real)0;
            real* oo = o + (size_t)oc * plane;
            for (size_t p = 0; p < plane; p++) oo[p] = b;
        }
        const real* x = in + (size_t)n * in_n;
        if (FN(pointwise)(cv)) {   // out[OC, HW] += weight[OC, C] . in[C, HW]
            gemm(MLB_NOTRANS, MLB_NOTRANS, cv->OC, (int)plane, cv->C, (real)1, weight, cv->C, x,
                 (int)plane, (real)1, o, (int)plane);
            continue;
        }
        const int band = FN(band_rows)(cv);
        for (int y0 = 0; y0 < OH; y0 += band) {
            int rows = y0 + band <= OH ? band : OH - y0;
            int P = rows * OW;
            FN(im2col)(ws, x, cv, OW, y0, rows);
            gemm(MLB_NOTRANS, MLB_NOTRANS, cv->OC, P, K, (real)1, weight, K, ws, P, (real)1,
                 o + (size_t)y0 * OW, (int)plane);
        }
    }
    free(owned);
    return MLB_OK;
}

static mlb_status FN(conv2d_backward_with)(FN(mlb_gemm_fn) gemm, real* din, real* dweight, real* dbias,
                                           const real* dout, const real* in, const real* weight, const mlb_conv2d* cv,
                                           real* ws) {
    MLB_TRY(mlb_conv2d_check(cv));
    if (!dout || (din && !weight) || (dweight && !in)) return mlb_fail(MLB_ERR_ARG, "conv2d backward: NULL buffer");
    const int OH = mlb_conv2d_out_h(cv), OW = mlb_conv2d_out_w(cv), K = cv->C * cv->KH * cv->KW;
    const size_t in_n = (size_t)cv->C * cv->H * cv->W, out_n = (size_t)cv->OC * OH * OW, plane = (size_t)OH * OW;
    if (dbias) {   // per channel, over images then pixels in order, in double
#pragma omp parallel for schedule(static) if ((size_t)cv->N * out_n >= COPS_PARALLEL_MIN)
        for (int oc = 0; oc < cv->OC; oc++) {
            double s = 0;
            for (int n = 0; n < cv->N; n++) {
                const real* d = dout + (size_t)n * out_n + (size_t)oc * plane;
                for (size_t p = 0; p < plane; p++) s += (double)d[p];
            }
            dbias[oc] += (real)s;
        }
    }
    if (!din && !dweight) return MLB_OK;
    real* owned;
    MLB_TRY(FN(conv_ws)(&ws, &owned, cv));
    for (int n = 0; n < cv->N; n++) {
        const real* d = dout + (size_t)n * out_n;
        if (FN(pointwise)(cv)) {
            if (din)   // din[C, HW] += weight^T[C, OC] . dout[OC, HW]
                gemm(MLB_TRANS, MLB_NOTRANS, cv->C, (int)plane, cv->OC, (real)1, weight, cv->C, d,
                     (int)plane, (real)1, din + (size_t)n * in_n, (int)plane);
            if (dweight)   // dweight[OC, C] += dout[OC, HW] . in^T[HW, C]
                gemm(MLB_NOTRANS, MLB_TRANS, cv->OC, cv->C, (int)plane, (real)1, d, (int)plane,
                     in + (size_t)n * in_n, (int)plane, (real)1, dweight, cv->C);
            continue;
        }
        const int band = FN(band_rows)(cv);
        for (int y0 = 0; y0 < OH; y0 += band) {
            int rows = y0 + band <= OH ? band : OH - y0;
            int P = rows * OW;
            const real* db = d + (size_t)y0 * OW;
            if (dweight) {   // dweight[OC, K] += dout_band[OC, P] . col^T[P, K]
                FN(im2col)(ws, in + (size_t)n * in_n, cv, OW, y0, rows);
                gemm(MLB_NOTRANS, MLB_TRANS, cv->OC, K, P, (real)1, db, (int)plane, ws, P, (real)1,
                     dweight, K);
            }
            if (din) {   // dcol[K, P] = weight^T[K, OC] . dout_band[OC, P], then scattered into din
                gemm(MLB_TRANS, MLB_NOTRANS, K, P, cv->OC, (real)1, weight, K, db, (int)plane,
                     (real)0, ws, P);
                FN(col2im_add)(din + (size_t)n * in_n, ws, cv, OW, y0, rows);
            }
        }
    }
    free(owned);
    return MLB_OK;
}

mlb_status FN(conv2d_forward)(real* out, const real* in, const real* weight, const real* bias,
                               const mlb_conv2d* cv, real* ws) {
    return FN(conv2d_forward_with)(GEMM, out, in, weight, bias, cv, ws);
}

mlb_status FN(conv2d_backward)(real* din, real* dweight, real* dbias, const real* dout, const real* in,
                                const real* weight, const mlb_conv2d* cv, real* ws) {
    return FN(conv2d_backward_with)(GEMM, din, dweight, dbias, dout, in, weight, cv, ws);
}

#ifndef MLB_F64
// bf16: the implicit GEMM of conv_bf16.c where it applies (the same bits as im2col + GEMM here).
mlb_status conv2d_forward_bf16(float* out, const float* in, const float* weight, const float* bias,
                               const mlb_conv2d* cv, float* ws) {
    if (out && in && weight && conv2d_bf16_implicit_applies(cv, 0))
        return conv2d_bf16_implicit_forward(out, in, weight, bias, cv, 0);
    return conv2d_forward_with(mlb_gemm_bf16, out, in, weight, bias, cv, ws);
}

mlb_status conv2d_backward_bf16(float* din, float* dweight, float* dbias, const float* dout, const float* in,
                                const float* weight, const mlb_conv2d* cv, float* ws) {
    if (din && dout && weight && conv2d_bf16_implicit_applies(cv, 1)) {
        MLB_TRY(conv2d_bf16_implicit_input_grad(din, dout, weight, cv));
        din = NULL;   // the weight's and bias's gradients below, if asked for
    }
    return conv2d_backward_with(mlb_gemm_bf16, din, dweight, dbias, dout, in, weight, cv, ws);
}
#endif

// ---- group norm ------------------------------------------------------------------------------------
// The activation and its derivative; SiLU (the VAE's and UNet's) inline, the rest through nn.h.
static inline real FN(gn_act)(mlb_activation act, real y) {
    if (act == MLB_ACT_IDENTITY) return y;
    if (act == MLB_ACT_SILU) return y / ((real)1 + R_EXP(-y));
    return FN(mlb_act)(act, y);
}
static inline real FN(gn_act_d1)(mlb_activation act, real y) {
    if (act == MLB_ACT_IDENTITY) return 1;
    if (act == MLB_ACT_SILU) {   // sigma(y) (1 + y (1 - sigma(y))), with sigma from the non-overflowing side
        real e = R_EXP(-R_FABS(y));
        real sg = y >= 0 ? (real)1 / ((real)1 + e) : e / ((real)1 + e);
        return sg * ((real)1 + y * ((real)1 - sg));
    }
    return FN(mlb_act_d1)(act, y);
}

// The kernels the float pass runs a group through (simd_rows.h: SiLU or identity, on a CPU with
// AVX2 or AVX-512), or scalar.
static mlb_simd_level FN(gn_vectorised)(mlb_activation act) {
#ifndef MLB_F64
    return act == MLB_ACT_IDENTITY || act == MLB_ACT_SILU ? mlb_simd_kernels() : MLB_SIMD_SCALAR;
#else
    (void)act;
    return MLB_SIMD_SCALAR;
#endif
}

static mlb_status FN(gn_check)(int N, int C, int HW, int G) {
    if (N < 0 || C < 0 || HW < 0 || G < 1)
        return mlb_fail(MLB_ERR_ARG, "group norm: bad shape [%d, %d, %d] with %d groups", N, C, HW, G);
    if (C % G != 0)
        return mlb_fail(MLB_ERR_ARG, "group norm: %d channels are not a multiple of the %d groups", C, G);
    return MLB_OK;
}

mlb_status FN(groupnorm_forward)(real* out, real* mean, real* rstd, const real* in, const real* weight,
                                  const real* bias, int N, int C, int HW, int G, real eps, mlb_activation act) {
    MLB_TRY(FN(gn_check)(N, C, HW, G));
    if (N == 0 || C == 0) return MLB_OK;
    if (!out || !in) return mlb_fail(MLB_ERR_ARG, "group norm: NULL buffer");
    const int Cg = C / G;
    const size_t M = (size_t)Cg * HW;
    const mlb_simd_level vec = FN(gn_vectorised)(act);
    (void)vec;   // the double pass never vectorises
#pragma omp parallel for schedule(static) if ((size_t)N * C * HW >= COPS_PARALLEL_MIN)
    for (int ng = 0; ng < N * G; ng++) {
        const real* x = in + (size_t)ng * M;   // the group's channels are consecutive in NCHW
        real* o = out + (size_t)ng * M;
#ifndef MLB_F64
        if (vec) {
            const int c0 = (ng % G) * Cg;
            double m, r;
            mlb_groupnorm_forward_group(vec, o, &m, &r, x, weight ? weight + c0 : NULL, bias ? bias + c0 : NULL, Cg, HW,
                                        eps, act == MLB_ACT_SILU);
            if (mean) mean[ng] = (real)m;
            if (rstd) rstd[ng] = (real)r;
            continue;
        }
#endif
        double m = 0, v = 0;
        for (size_t i = 0; i < M; i++) m += (double)x[i];
        m = M ? m / (double)M : 0;
        for (size_t i = 0; i < M; i++) { double d = (double)x[i] - m; v += d * d; }
        v = M ? v / (double)M : 0;
        double r = 1.0 / sqrt(v + (double)eps);
        int g = ng % G;
        for (int cc = 0; cc < Cg; cc++) {
            int c = g * Cg + cc;
            real w = weight ? weight[c] : (real)1, b = bias ? bias[c] : (real)0;
            const real* xc = x + (size_t)cc * HW;
            real* oc = o + (size_t)cc * HW;
            for (int p = 0; p < HW; p++) {
                real y = (real)(((double)xc[p] - m) * r) * w + b;
                oc[p] = FN(gn_act)(act, y);
            }
        }
        if (mean) mean[ng] = (real)m;
        if (rstd) rstd[ng] = (real)r;
    }
    return MLB_OK;
}

mlb_status FN(groupnorm_backward)(real* din, real* dweight, real* dbias, const real* dout, const real* in,
                                   const real* weight, const real* bias, const real* mean, const real* rstd,
                                   int N, int C, int HW, int G, mlb_activation act) {
    MLB_TRY(FN(gn_check)(N, C, HW, G));
    if (N == 0 || C == 0 || (!din && !dweight && !dbias)) return MLB_OK;
    if (!dout || !in || !mean || !rstd) return mlb_fail(MLB_ERR_ARG, "group norm backward: NULL buffer");
    const int Cg = C / G;
    const size_t M = (size_t)Cg * HW;
    const mlb_simd_level vec = FN(gn_vectorised)(act);
    (void)vec;   // the double pass never vectorises
    double* part = NULL;   // [N, C, 2]: per image and channel, sum gy * xhat and sum gy
    if (dweight || dbias) {
        part = malloc((size_t)N * C * 2 * sizeof(double));
        if (!part) return mlb_fail(MLB_ERR_NOMEM, "group norm backward: out of memory for %d x %d sums", N, C);
    }
#pragma omp parallel for schedule(static) if ((size_t)N * C * HW >= COPS_PARALLEL_MIN)
    for (int ng = 0; ng < N * G; ng++) {
        const real* x = in + (size_t)ng * M;
        const real* d = dout + (size_t)ng * M;
        real m = mean[ng], r = rstd[ng];
        int g = ng % G, n = ng / G;
#ifndef MLB_F64
        if (vec) {
            const int c0 = g * Cg;
            mlb_groupnorm_backward_group(vec, din ? din + (size_t)ng * M : NULL, part ? part + ((size_t)n * C + c0) * 2 : NULL,
                                         d, x, weight ? weight + c0 : NULL, bias ? bias + c0 : NULL, m, r, Cg, HW,
                                         act == MLB_ACT_SILU);
            continue;
        }
#endif
        double s1 = 0, s2 = 0;   // sums of g and g * xhat over the group
        for (int cc = 0; cc < Cg; cc++) {
            int c = g * Cg + cc;
            real w = weight ? weight[c] : (real)1, b = bias ? bias[c] : (real)0;
            double pw = 0, pb = 0;
            for (int p = 0; p < HW; p++) {
                size_t i = (size_t)cc * HW + p;
                real xh = (x[i] - m) * r;
                real gy = d[i] * FN(gn_act_d1)(act, xh * w + b);
                pw += (double)gy * (double)xh;
                pb += (double)gy;
            }
            s1 += pb * (double)w;
            s2 += pw * (double)w;
            if (part) { part[((size_t)n * C + c) * 2] = pw; part[((size_t)n * C + c) * 2 + 1] = pb; }
        }
        if (!din) continue;
        real mg = (real)(M ? s1 / (double)M : 0), mgx = (real)(M ? s2 / (double)M : 0);
        real* dx = din + (size_t)ng * M;
        for (int cc = 0; cc < Cg; cc++) {
            int c = g * Cg + cc;
            real w = weight ? weight[c] : (real)1, b = bias ? bias[c] : (real)0;
            for (int p = 0; p < HW; p++) {
                size_t i = (size_t)cc * HW + p;
                real xh = (x[i] - m) * r;
                real gy = d[i] * FN(gn_act_d1)(act, xh * w + b);
                dx[i] += r * (gy * w - mg - xh * mgx);
            }
        }
    }
    if (part) {
        for (int c = 0; c < C; c++) {
            double sw = 0, sb = 0;
            for (int n = 0; n < N; n++) { sw += part[((size_t)n * C + c) * 2]; sb += part[((size_t)n * C + c) * 2 + 1]; }
            if (dweight) dweight[c] += (real)sw;
            if (dbias) dbias[c] += (real)sb;
        }
        free(part);
    }
    return MLB_OK;
}

// ---- nearest 2x upsampling -----------------------------------------------------------------------
void FN(upsample_nearest2x_forward)(real* out, const real* in, int N, int C, int H, int W) {
    if (N <= 0 || C <= 0 || H <= 0 || W <= 0) return;
    const int NC = N * C, W2 = 2 * W;
#pragma omp parallel for schedule(static) if ((size_t)NC * H * W >= COPS_PARALLEL_MIN / 4)
    for (int nc = 0; nc < NC; nc++) {
        const real* s = in + (size_t)nc * H * W;
        real* d = out + (size_t)nc * 4 * H * W;
        for (int y = 0; y < H; y++) {
            real* r0 = d + (size_t)(2 * y) * W2;
            const real* sr = s + (size_t)y * W;
            for (int x = 0; x < W; x++) r0[2 * x] = r0[2 * x + 1] = sr[x];
            memcpy(r0 + W2, r0, (size_t)W2 * sizeof(real));
        }
    }
}

void FN(upsample_nearest2x_backward)(real* din, const real* dout, int N, int C, int H, int W) {
    if (N <= 0 || C <= 0 || H <= 0 || W <= 0) return;
    const int NC = N * C, W2 = 2 * W;
#pragma omp parallel for schedule(static) if ((size_t)NC * H * W >= COPS_PARALLEL_MIN / 4)
    for (int nc = 0; nc < NC; nc++) {
        const real* s = dout + (size_t)nc * 4 * H * W;
        real* d = din + (size_t)nc * H * W;
        for (int y = 0; y < H; y++) {
            const real* r0 = s + (size_t)(2 * y) * W2;
            const real* r1 = r0 + W2;
            real* dr = d + (size_t)y * W;
            for (int x = 0; x < W; x++) dr[x] += (r0[2 * x] + r0[2 * x + 1]) + (r1[2 * x] + r1[2 * x + 1]);
        }
    }
}

// ---- batched transpose -----------------------------------------------------------------------------
#define COPS_TILE 32
void FN(transpose_last2)(real* out, const real* in, int N, int R, int S, int accumulate) {
    if (N <= 0 || R <= 0 || S <= 0) return;
    const int tr = (R + COPS_TILE - 1) / COPS_TILE, ts = (S + COPS_TILE - 1) / COPS_TILE;
    const int64_t tiles = (int64_t)N * tr * ts;
#pragma omp parallel for schedule(static) if ((size_t)N * R * S >= COPS_PARALLEL_MIN)
    for (int64_t t = 0; t < tiles; t++) {
        int n = (int)(t / ((int64_t)tr * ts)), rem = (int)(t % ((int64_t)tr * ts));
        int r0 = (rem / ts) * COPS_TILE, s0 = (rem % ts) * COPS_TILE;
        int r1 = r0 + COPS_TILE < R ? r0 + COPS_TILE : R, s1 = s0 + COPS_TILE < S ? s0 + COPS_TILE : S;
        const real* a = in + (size_t)n * R * S;
        real* b = out + (size_t)n * R * S;
        for (int s = s0; s < s1; s++)
            for (int r = r0; r < r1; r++) {
                if (accumulate) b[(size_t)s * R + r] += a[(size_t)r * S + s];
                else b[(size_t)s * R + r] = a[(size_t)r * S + s];
            }
    }
}

// ---- scaled dot-product attention ------------------------------------------------------------------
static mlb_status FN(sdpa_check)(int B, int Tq, int Tk, int C, int NH, int ldq, int ldkv) {
    if (B < 0 || Tq < 0 || Tk < 0 || C <= 0 || NH <= 0)
        return mlb_fail(MLB_ERR_ARG, "attention: bad shape B %d, Tq %d, Tk %d, C %d, %d heads", B, Tq, Tk, C, NH);
    if (C % NH != 0) return mlb_fail(MLB_ERR_ARG, "attention: width %d is not a multiple of the %d heads", C, NH);
    if (ldq < C || ldkv < C)
        return mlb_fail(MLB_ERR_ARG, "attention: token strides %d (q), %d (k, v) are less than the width %d", ldq,
                        ldkv, C);
    if (B > 0 && Tq > 0 && Tk < 1) return mlb_fail(MLB_ERR_ARG, "attention: %d queries but no keys", Tq);
    return MLB_OK;
}
// The blocks both passes walk: *rows queries per score block (att_rows), and two score blocks of
// *rows x Tk at *ws, the caller's (sdpa_workspace_size) or allocated here into *owned, which the
// caller frees (NULL when the caller gave one)
static mlb_status FN(att_blocks)(real** ws, real** owned, size_t* rows, int Tq, int Tk, const char* op) {
    *rows = FN(att_rows)(Tq, Tk);
    *owned = NULL;
    if (*ws) return MLB_OK;
    *owned = malloc(2 * *rows * (size_t)Tk * sizeof(real));
    if (!*owned) return mlb_fail(MLB_ERR_NOMEM, "%s: out of memory for a %zu x %d score block", op, *rows, Tk);
    *ws = *owned;
    return MLB_OK;
}


// Row p[0..n): p <- e^(p - max p); returns the max, *sum = the sum of the new p. The float pass
// takes simd_rows.h's row on a CPU with AVX2 or AVX-512 (fp32 partial sums); the double pass, the
// finite-difference reference, keeps libm's exp and a double sum.
static real FN(softmax_row_exp)(real* p, int n, double* sum) {
#ifndef MLB_F64
    const mlb_simd_level lv = mlb_simd_kernels();
    if (lv != MLB_SIMD_SCALAR) {
        float sumf;
        real mx = mlb_softmax_row(lv, p, n, &sumf);
        *sum = sumf;
        return mx;
    }
#endif
    real mx = p[0];
    for (int s = 1; s < n; s++) if (p[s] > mx) mx = p[s];
    double acc = 0;
    for (int s = 0; s < n; s++) { p[s] = R_EXP(p[s] - mx); acc += (double)p[s]; }
    *sum = acc;
    return mx;
}

mlb_status FN(sdpa_forward)(real* out, real* lse, const real* q, const real* k, const real* v, int B, int Tq,
                             int Tk, int C, int NH, int ldq, int ldkv, real* ws) {
    MLB_TRY(FN(sdpa_check)(B, Tq, Tk, C, NH, ldq, ldkv));
    if (B == 0 || Tq == 0) return MLB_OK;
    if (!out || !q || !k || !v) return mlb_fail(MLB_ERR_ARG, "attention: NULL buffer");
    const int hd = C / NH;
    const real scale = (real)(1.0 / sqrt((double)hd));
    size_t rows;
    real* owned;
    MLB_TRY(FN(att_blocks)(&ws, &owned, &rows, Tq, Tk, "attention"));
    real* S = ws;
    for (int b = 0; b < B; b++)
        for (int h = 0; h < NH; h++) {
            const real* kb = k + (size_t)b * Tk * ldkv + (size_t)h * hd;
            const real* vb = v + (size_t)b * Tk * ldkv + (size_t)h * hd;
            for (int t0 = 0; t0 < Tq; t0 += (int)rows) {
                int nr = t0 + (int)rows <= Tq ? (int)rows : Tq - t0;
                const real* qb = q + ((size_t)b * Tq + t0) * ldq + (size_t)h * hd;
                GEMM(MLB_NOTRANS, MLB_TRANS, nr, Tk, hd, scale, qb, ldq, kb, ldkv, (real)0, S, Tk);
#pragma omp parallel for schedule(static) if ((size_t)nr * Tk >= COPS_PARALLEL_MIN)
                for (int i = 0; i < nr; i++) {
                    real* p = S + (size_t)i * Tk;
                    double sum;
                    real mx = FN(softmax_row_exp)(p, Tk, &sum);
                    real inv = (real)(1.0 / sum);
                    for (int s = 0; s < Tk; s++) p[s] *= inv;
                    if (lse) lse[((size_t)b * NH + h) * Tq + t0 + i] = (real)((double)mx + log(sum));
                }
                GEMM(MLB_NOTRANS, MLB_NOTRANS, nr, hd, Tk, (real)1, S, Tk, vb, ldkv, (real)0,
                     out + ((size_t)b * Tq + t0) * C + (size_t)h * hd, C);
            }
        }
    free(owned);
    return MLB_OK;
}

// The backward's rows: p <- e^(p - c) and g <- p (g - d) scale. As softmax_row_exp: the float pass
// takes simd_rows.h's rows on a CPU with AVX2 or AVX-512 (the exponential clamped at 0, as a
// probability is at most 1); the double pass, the finite-difference reference, keeps libm's exp.
static void FN(exp_shifted_row)(real* p, int n, real c) {
#ifndef MLB_F64
    const mlb_simd_level lv = mlb_simd_kernels();
    if (lv != MLB_SIMD_SCALAR) {
        mlb_exp_shifted_row(lv, p, n, c);
        return;
    }
#endif
    for (int s = 0; s < n; s++) p[s] = R_EXP(p[s] - c);
}
static void FN(softmax_grad_row)(real* g, const real* p, int n, real d, real scale) {
#ifndef MLB_F64
    const mlb_simd_level lv = mlb_simd_kernels();
    if (lv != MLB_SIMD_SCALAR) {
        mlb_softmax_grad_row(lv, g, p, n, d, scale);
        return;
    }
#endif
    for (int s = 0; s < n; s++) g[s] = p[s] * (g[s] - d) * scale;
}

static mlb_status FN(sdpa_backward_with)(FN(mlb_gemm_fn) gemm, real* dq, real* dk, real* dv, const real* dout,
                                         const real* out, const real* lse, const real* q, const real* k, const real* v,
                                         int B, int Tq, int Tk, int C, int NH, int ldq, int ldkv, real* ws) {
    MLB_TRY(FN(sdpa_check)(B, Tq, Tk, C, NH, ldq, ldkv));
    if (B == 0 || Tq == 0 || (!dq && !dk && !dv)) return MLB_OK;
    if (!dout || !out || !lse || !q || !k || !v) return mlb_fail(MLB_ERR_ARG, "attention backward: NULL buffer");
    const int hd = C / NH;
    const real scale = (real)(1.0 / sqrt((double)hd));
    size_t rows;
    real* owned;
    MLB_TRY(FN(att_blocks)(&ws, &owned, &rows, Tq, Tk, "attention backward"));
    real* P = ws;
    real* dP = ws + rows * (size_t)Tk;
    for (int b = 0; b < B; b++)
        for (int h = 0; h < NH; h++) {
            const real* kb = k + (size_t)b * Tk * ldkv + (size_t)h * hd;
            const real* vb = v + (size_t)b * Tk * ldkv + (size_t)h * hd;
            for (int t0 = 0; t0 < Tq; t0 += (int)rows) {
                int nr = t0 + (int)rows <= Tq ? (int)rows : Tq - t0;
                size_t tok = (size_t)b * Tq + t0;
                const real* qb = q + tok * ldq + (size_t)h * hd;
                const real* dob = dout + tok * C + (size_t)h * hd;
                const real* ob = out + tok * C + (size_t)h * hd;
                const real* lb = lse + ((size_t)b * NH + h) * Tq + t0;
                gemm(MLB_NOTRANS, MLB_TRANS, nr, Tk, hd, scale, qb, ldq, kb, ldkv, (real)0, P, Tk);
#pragma omp parallel for schedule(static) if ((size_t)nr * Tk >= COPS_PARALLEL_MIN)
                for (int i = 0; i < nr; i++) FN(exp_shifted_row)(P + (size_t)i * Tk, Tk, lb[i]);
                if (dv)   // dv[Tk, hd] += P^T . dout_block
                    gemm(MLB_TRANS, MLB_NOTRANS, Tk, hd, nr, (real)1, P, Tk, dob, C, (real)1,
                         dv + (size_t)b * Tk * ldkv + (size_t)h * hd, ldkv);
                if (!dq && !dk) continue;
                // dP = dout_block . v^T; dS = P * (dP - rowsum(dout * out)) * scale
                gemm(MLB_NOTRANS, MLB_TRANS, nr, Tk, hd, (real)1, dob, C, vb, ldkv, (real)0, dP, Tk);
#pragma omp parallel for schedule(static) if ((size_t)nr * Tk >= COPS_PARALLEL_MIN)
                for (int i = 0; i < nr; i++) {
                    double di = 0;
                    const real* a = dob + (size_t)i * C;
                    const real* o = ob + (size_t)i * C;
                    for (int d = 0; d < hd; d++) di += (double)a[d] * (double)o[d];
                    FN(softmax_grad_row)(dP + (size_t)i * Tk, P + (size_t)i * Tk, Tk, (real)di, scale);
                }
                if (dq)   // dq_block += dS . k
                    gemm(MLB_NOTRANS, MLB_NOTRANS, nr, hd, Tk, (real)1, dP, Tk, kb, ldkv, (real)1,
                         dq + tok * ldq + (size_t)h * hd, ldq);
                if (dk)   // dk += dS^T . q_block
                    gemm(MLB_TRANS, MLB_NOTRANS, Tk, hd, nr, (real)1, dP, Tk, qb, ldq, (real)1,
                         dk + (size_t)b * Tk * ldkv + (size_t)h * hd, ldkv);
            }
        }
    free(owned);
    return MLB_OK;
}

mlb_status FN(sdpa_backward)(real* dq, real* dk, real* dv, const real* dout, const real* out, const real* lse,
                              const real* q, const real* k, const real* v, int B, int Tq, int Tk, int C, int NH,
                              int ldq, int ldkv, real* ws) {
    return FN(sdpa_backward_with)(GEMM, dq, dk, dv, dout, out, lse, q, k, v, B, Tq, Tk, C, NH, ldq, ldkv, ws);
}

#ifndef MLB_F64
// Its five products on the bf16 GEMM (the recomputed scores and dS in fp32 between them): sdpa_backward's
// bits where the CPU lacks AVX-512 BF16 (mlb_gemm_bf16 is then mlb_gemm).
mlb_status sdpa_backward_bf16(float* dq, float* dk, float* dv, const float* dout, const float* out, const float* lse,
                              const float* q, const float* k, const float* v, int B, int Tq, int Tk, int C, int NH,
                              int ldq, int ldkv, float* ws) {
    return sdpa_backward_with(mlb_gemm_bf16, dq, dk, dv, dout, out, lse, q, k, v, B, Tq, Tk, C, NH, ldq, ldkv, ws);
}
#endif
