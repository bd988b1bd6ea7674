// Transformer ops: layer norm, multi-head self-attention, embedding lookup (transformer_ops.h).
// Dual-compiled (float / double _f64) like the other MLB_DUAL_SOURCES, see core/real.h.
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/error.h"
#include "matlaber/transformer_ops.h"
#include "core/real.h"
#include "nn/simd_rows.h"

// Below this many values an op stays on one thread (the fork/join costs more than the work).
#define TOPS_PARALLEL_MIN 32768
// dweight/dbias of the layer norm backward: column blocks, each summed over rows in order.
#define TOPS_COL_BLOCK 64


// The float pass on a CPU with AVX2 or AVX-512: a row's sums in the lanes (nn/simd_rows.h); the
// scalar loop's chain of double adds was ~3% of a `tiny` generation (the UNet's transformer blocks).
void FN(layernorm_forward)(real* out, real* mean, real* rstd, const real* in, const real* weight,
                            const real* bias, int N, int C, real eps) {
    if (N <= 0) return;
#ifndef MLB_F64
    const mlb_simd_level level = mlb_simd_kernels();
    if (level != MLB_SIMD_SCALAR) {
#pragma omp parallel for schedule(static) if ((int64_t)N * C >= TOPS_PARALLEL_MIN)
        for (int n = 0; n < N; n++)
            mlb_layernorm_row(level, out + (size_t)n * C, mean ? mean + n : NULL, rstd ? rstd + n : NULL,
                              in + (size_t)n * C, weight, bias, C, eps);
        return;
    }
#endif
#pragma omp parallel for schedule(static) if ((int64_t)N * C >= TOPS_PARALLEL_MIN)
    for (int n = 0; n < N; n++) {
        const real* x = in + (size_t)n * C;
        real* o = out + (size_t)n * C;
        double m = 0, v = 0;
        for (int c = 0; c < C; c++) m += (double)x[c];
        m = C > 0 ? m / C : 0;
        for (int c = 0; c < C; c++) { double d = (double)x[c] - m; v += d * d; }
        v = C > 0 ? v / C : 0;
        double r = 1.0 / sqrt(v + (double)eps);
        for (int c = 0; c < C; c++) {   // x - mean in double: no cancellation for rows far from 0
            real xh = (real)(((double)x[c] - m) * r);
            o[c] = xh * (weight ? weight[c] : (real)1) + (bias ? bias[c] : (real)0);
        }
        if (mean) mean[n] = (real)m;
        if (rstd) rstd[n] = (real)r;
    }
}

void FN(layernorm_backward)(real* din, real* dweight, real* dbias, const real* dout, const real* in,
                             const real* weight, const real* mean, const real* rstd, int N, int C) {
    if (N <= 0 || C <= 0) return;
    if (din) {
#pragma omp parallel for schedule(static) if ((int64_t)N * C >= TOPS_PARALLEL_MIN)
        for (int n = 0; n < N; n++) {
            const real* x = in + (size_t)n * C;
            const real* d = dout + (size_t)n * C;
            real* dx = din + (size_t)n * C;
            real m = mean[n], r = rstd[n];
            double sg = 0, sgx = 0;   // sums of g and g * xhat
            for (int c = 0; c < C; c++) {
                real xh = (x[c] - m) * r;
                real g = d[c] * (weight ? weight[c] : (real)1);
                sg += (double)g;
                sgx += (double)g * (double)xh;
            }
            real mg = (real)(sg / C), mgx = (real)(sgx / C);
            for (int c = 0; c < C; c++) {
                real xh = (x[c] - m) * r;
                real g = d[c] * (weight ? weight[c] : (real)1);
                dx[c] += r * (g - mg - xh * mgx);
            }
        }
    }
    if (dweight || dbias) {
        int n_blocks = (C + TOPS_COL_BLOCK - 1) / TOPS_COL_BLOCK;
#pragma omp parallel for schedule(static) if ((int64_t)N * C >= TOPS_PARALLEL_MIN)
        for (int blk = 0; blk < n_blocks; blk++) {
            int c0 = blk * TOPS_COL_BLOCK, c1 = c0 + TOPS_COL_BLOCK < C ? c0 + TOPS_COL_BLOCK : C;
            double aw[TOPS_COL_BLOCK] = {0}, ab[TOPS_COL_BLOCK] = {0};
            for (int n = 0; n < N; n++) {
                const real* x = in + (size_t)n * C;
                const real* d = dout + (size_t)n * C;
                real m = mean[n], r = rstd[n];
                for (int c = c0; c < c1; c++) {
                    aw[c - c0] += (double)d[c] * (double)((x[c] - m) * r);
                    ab[c - c0] += (double)d[c];
                }
            }
            for (int c = c0; c < c1; c++) {
                if (dweight) dweight[c] += (real)aw[c - c0];
                if (dbias) dbias[c] += (real)ab[c - c0];
            }
        }
    }
}

// One (batch, head) pair: rows t = 0..T-1 of the attention, p written to prob (T values per row,
// stride T; a row buffer reused per query when the caller keeps no probabilities).
static void FN(attention_head)(real* out, real* prob, int keep_rows, const real* q, const real* k,
                                const real* v, int ld, int T, int C, int hd, int causal, real scale) {
    for (int t = 0; t < T; t++) {
        const real* qt = q + (size_t)t * ld;
        real* p = keep_rows ? prob + (size_t)t * T : prob;
        int n = causal ? t + 1 : T;
        real mx = -INFINITY;
        for (int s = 0; s < n; s++) {
            const real* ks = k + (size_t)s * ld;
            real dot = 0;
            for (int i = 0; i < hd; i++) dot += qt[i] * ks[i];
            p[s] = dot * scale;
            if (p[s] > mx) mx = p[s];
        }
        double sum = 0;
        for (int s = 0; s < n; s++) { p[s] = R_EXP(p[s] - mx); sum += (double)p[s]; }
        real inv = (real)(1.0 / sum);
        for (int s = 0; s < n; s++) p[s] *= inv;
        for (int s = n; s < T && keep_rows; s++) p[s] = 0;
        real* o = out + (size_t)t * C;
        for (int i = 0; i < hd; i++) o[i] = 0;
        for (int s = 0; s < n; s++) {
            const real* vs = v + (size_t)s * ld;
            real ps = p[s];
            for (int i = 0; i < hd; i++) o[i] += ps * vs[i];
        }
    }
}

mlb_status FN(attention_forward)(real* out, real* att, const real* q, const real* k, const real* v, int ld,
                                  int B, int T, int C, int NH, int causal) {
    if (B < 0 || T < 0 || C <= 0 || NH <= 0)
        return mlb_fail(MLB_ERR_ARG, "attention: bad shape B %d, T %d, C %d, %d heads", B, T, C, NH);
    if (C % NH != 0)
        return mlb_fail(MLB_ERR_ARG, "attention: width %d is not a multiple of the %d heads", C, NH);
    if (ld < C) return mlb_fail(MLB_ERR_ARG, "attention: token stride %d is less than the width %d", ld, C);
    if (B == 0 || T == 0) return MLB_OK;
    if (!out || !q || !k || !v) return mlb_fail(MLB_ERR_ARG, "attention: NULL buffer");
    int hd = C / NH;
    real scale = (real)(1.0 / sqrt((double)hd));
    int n_pairs = B * NH, failed = 0;
#pragma omp parallel if ((int64_t)n_pairs * T * T * hd >= TOPS_PARALLEL_MIN)
    {
        real* row = att ? NULL : malloc((size_t)T * sizeof(real));
        if (!att && !row) {
#pragma omp atomic write
            failed = 1;
        }
#pragma omp for schedule(static)
        for (int bh = 0; bh < n_pairs; bh++) {
            if (!att && !row) continue;
            int b = bh / NH, h = bh % NH;
            size_t tok0 = (size_t)b * T;
            FN(attention_head)(out + tok0 * C + (size_t)h * hd, att ? att + (size_t)bh * T * T : row, att != NULL,
                                q + tok0 * ld + (size_t)h * hd, k + tok0 * ld + (size_t)h * hd,
                                v + tok0 * ld + (size_t)h * hd, ld, T, C, hd, causal, scale);
        }
        free(row);
    }
    if (failed) return mlb_fail(MLB_ERR_NOMEM, "attention: out of memory for a %d-token row", T);
    return MLB_OK;
}

mlb_status FN(embedding_forward)(real* out, const int* tokens, const real* wte, const real* wpe,
                                  int B, int T, int C, int V) {
    if (B < 0 || T < 0 || C < 0 || V < 0)
        return mlb_fail(MLB_ERR_ARG, "embedding: bad shape B %d, T %d, C %d, vocabulary %d", B, T, C, V);
    for (int b = 0; b < B; b++)
        for (int t = 0; t < T; t++) {
            int id = tokens[(size_t)b * T + t];
            if (id < 0 || id >= V)
                return mlb_fail(MLB_ERR_ARG, "token %d at [%d, %d] is outside the vocabulary [0, %d)", id, b, t, V);
        }
#pragma omp parallel for schedule(static) if ((int64_t)B * T * C >= TOPS_PARALLEL_MIN)
    for (int bt = 0; bt < B * T; bt++) {
        const real* e = wte + (size_t)tokens[bt] * C;
        const real* p = wpe ? wpe + (size_t)(bt % T) * C : NULL;
        real* o = out + (size_t)bt * C;
        for (int c = 0; c < C; c++) o[c] = p ? e[c] + p[c] : e[c];
    }
    return MLB_OK;
}
