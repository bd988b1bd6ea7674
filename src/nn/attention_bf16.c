// Scaled dot-product attention for the CPU's bf16 op table (backend.h): the contract of
// sdpa_forward (conv_ops.h), with both products on the bf16 GEMM kernel (gemm_bf16.c: bf16
// operands, fp32 sums) and the softmax in fp32 with a vectorised exp.
//
// Why: in fp32 the SD 1.5 UNet's attention ran at ~48 GFLOP/s, 45% of a bf16 CFG step
// (docs/benchmarks.md): each score block went through OpenBLAS at K = 40 (one head), then a scalar
// expf per score, then a second GEMM at N = 40. Here, head after head, the keys and values are
// packed to bf16 once (gemm_bf16.h) and the queries cut into blocks of BLOCK_ROWS, each done whole
// by one thread:
//   S[r, Tk]  = scale · Q_blk · K^T           (bf16 GEMM, K = head width)
//   S        <- exp(S - rowmax), rowsum in fp32 (AVX-512, 16 lanes, a fixed order)
//   O^T[hd, r] = V^T · S^T                     (bf16 GEMM; hd is the short side: 14-row panels fit
//                                               40 / 64 / 80 / 160 better than 32-column ones)
//   out[t, d] = O^T[d, t] / rowsum[t];  lse[t] = rowmax + log(rowsum)
// A block's scores (BLOCK_ROWS x Tk fp32: 1 MB at Tk = 4096) stay in the core's L2 between the
// three passes. No task's arithmetic depends on which thread runs it, so the result is bitwise the
// same on any thread count. Without AVX-512 BF16 (or with it forced off) it is sdpa_forward: the
// fp32 bits, like every bf16 op's fallback.
#include <math.h>
#include <stdint.h>
#include <stdlib.h>
#include <omp.h>
#include "matlaber/conv_ops.h"
#include "matlaber/error.h"
#include "matlaber/nn.h"
#include "nn/gemm_bf16.h"
#include "nn/simd_rows.h"

// Queries per task. Measured on 2 Zen 4 cores before the per-head packing: 28 rows 52, 64 rows 77,
// 256 rows 86 GFLOP/s per thread (then the keys were packed per block); not re-tuned since.
#define BLOCK_ROWS 64

#if defined(__x86_64__) && defined(__GNUC__) && (__GNUC__ >= 10 || defined(__clang__))
#define MLB_ATT_KERNEL 1
#endif

mlb_status sdpa_forward_bf16(float* out, float* lse, const float* q, const float* k, const float* v, int B, int Tq,
                             int Tk, int C, int NH, int ldq, int ldkv) {
#ifdef MLB_ATT_KERNEL
    if (!mlb_gemm_bf16_native()) return sdpa_forward(out, lse, q, k, v, B, Tq, Tk, C, NH, ldq, ldkv, NULL);
    // the shape checks and messages are sdpa_forward's (an empty call does nothing there either)
    if (B <= 0 || Tq <= 0 || C <= 0 || NH <= 0 || C % NH || ldq < C || ldkv < C || Tk < 1 || !out || !q || !k || !v)
        return sdpa_forward(out, lse, q, k, v, B, Tq, Tk, C, NH, ldq, ldkv, NULL);
    const int hd = C / NH, blocks = (Tq + BLOCK_ROWS - 1) / BLOCK_ROWS;
    const float scale = (float)(1.0 / sqrt((double)hd));
    // per head, packed once for all its query blocks: K^T as the first product's B, V^T as the second's A
    const size_t kw = mlb_gemm_bf16_packed_words(1, Tk, hd), vw = mlb_gemm_bf16_packed_words(0, hd, Tk);
    uint32_t* kv_packed = malloc(sizeof(uint32_t) * (kw + vw));
    if (!kv_packed) return mlb_fail(MLB_ERR_NOMEM, "attention (bf16): out of memory for a head's packed keys");
    int failed = 0;
#pragma omp parallel if (blocks > 1 && (int64_t)Tq * Tk * hd >= (1 << 20))
    {
        // per thread: one block's scores [BLOCK_ROWS, Tk], its O^T [hd, BLOCK_ROWS]
        float* S = malloc(sizeof(float) * ((size_t)BLOCK_ROWS * Tk + (size_t)hd * BLOCK_ROWS));
        float* OT = S ? S + (size_t)BLOCK_ROWS * Tk : NULL;
        if (!S) {
#pragma omp atomic write
            failed = 1;
        }
        for (int bh = 0; bh < B * NH; bh++) {
            const int b = bh / NH, h = bh % NH;
            const float* kb = k + (size_t)b * Tk * ldkv + (size_t)h * hd;
            const float* vb = v + (size_t)b * Tk * ldkv + (size_t)h * hd;
            const mlb_bf16_operand kop = {kb, 0, ldkv, kv_packed, NULL, NULL}, vop = {vb, 0, ldkv, kv_packed + kw, NULL, NULL};
#pragma omp sections
            {
#pragma omp section
                mlb_gemm_bf16_pack(1, 1, Tk, hd, &kop, kv_packed);
#pragma omp section
                mlb_gemm_bf16_pack(0, 1, hd, Tk, &vop, kv_packed + kw);
            }
#pragma omp for schedule(static)
            for (int blk = 0; blk < blocks; blk++) {
                if (!S) continue;
                const int t0 = blk * BLOCK_ROWS, nr = Tq - t0 < BLOCK_ROWS ? Tq - t0 : BLOCK_ROWS;
                const float* qb = q + ((size_t)b * Tq + t0) * ldq + (size_t)h * hd;
                const mlb_bf16_operand qop = {qb, 0, ldq, NULL, NULL, NULL}, sop = {S, 0, Tk, NULL, NULL, NULL};
                mlb_gemm_bf16_kernel(0, 1, nr, Tk, hd, scale, &qop, &kop, 0.0f, S, Tk);
                float inv[BLOCK_ROWS];
                for (int i = 0; i < nr; i++) {
                    float sum, mx = mlb_softmax_row_avx512(S + (size_t)i * Tk, Tk, &sum);
                    inv[i] = 1.0f / sum;
                    if (lse) lse[((size_t)b * NH + h) * Tq + t0 + i] = mx + logf(sum);
                }
                mlb_gemm_bf16_kernel(1, 1, hd, nr, Tk, 1.0f, &vop, &sop, 0.0f, OT, nr);
                float* ob = out + ((size_t)b * Tq + t0) * C + (size_t)h * hd;
                for (int i = 0; i < nr; i++)
                    for (int d = 0; d < hd; d++) ob[(size_t)i * C + d] = OT[(size_t)d * nr + i] * inv[i];
            }
        }
        free(S);
    }
    free(kv_packed);
    if (failed)
        return mlb_fail(MLB_ERR_NOMEM, "attention (bf16): out of memory for a %d x %d score block", BLOCK_ROWS, Tk);
    return MLB_OK;
#else
    return sdpa_forward(out, lse, q, k, v, B, Tq, Tk, C, NH, ldq, ldkv, NULL);
#endif
}
