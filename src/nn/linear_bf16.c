// linear_forward on the bf16 GEMM kernel (gemm_bf16.c) with the weight packed once: per call for
// fp32 weights (linear_forward_bf16), or at load for a frozen model's (linear_forward_bf16_packed,
// the UNet with bf16_weights). Both cut the rows of `in` into tasks of whole kernel calls against
// the one packed weight, so they give the same bits as each other on any thread count.
//
// Why: through mlb_gemm_bf16's shards every shard packed the weight again, on every call; with the
// SD 1.5 UNet's weights that packing was ~15% of a bf16 CFG step (perf, docs/benchmarks.md).
//
//   out[B, OC] = bias + in[B, C] · W[OC, C]^T     (W as the kernel's B operand, transposed)
#include <omp.h>
#include <stdint.h>
#include <stdlib.h>
#include "matlaber/nn.h"
#include "nn/gemm_bf16.h"

// Rows per task: at most one group of the kernel's packed A panels (24 x 14 rows), at least one
// panel, and small enough that a short input (77 context tokens) still fills both cores.
#define MAX_ROWS (24 * MLB_GEMM_BF16_MR)

static void linear_tiles(float* out, const float* in, const mlb_bf16_operand* w, const float* bias, int B, int C,
                         int OC) {
    const int threads = omp_get_max_threads();
    int rows = (B + 2 * threads - 1) / (2 * threads);
    rows = (rows + MLB_GEMM_BF16_MR - 1) / MLB_GEMM_BF16_MR * MLB_GEMM_BF16_MR;
    if (rows > MAX_ROWS) rows = MAX_ROWS;
    const int tasks = (B + rows - 1) / rows;
#pragma omp parallel for schedule(dynamic) if (tasks > 1 && (int64_t)B * C * OC >= ((int64_t)1 << 20))
    for (int t = 0; t < tasks; t++) {
        const int r0 = t * rows, m = B - r0 < rows ? B - r0 : rows;
        float* o = out + (size_t)r0 * OC;
        for (int i = 0; i < m; i++)   // the sums are added to the bias (beta = 1), as linear_forward does
            for (int j = 0; j < OC; j++) o[(size_t)i * OC + j] = bias ? bias[j] : 0.0f;
        if (C <= 0) continue;
        const mlb_bf16_operand a = {in, (size_t)r0 * C, C, NULL, NULL, NULL};
        mlb_gemm_bf16_kernel(0, 1, m, OC, C, 1.0f, &a, w, 1.0f, o, OC);
    }
}

void linear_forward_bf16(float* out, const float* in, const float* weight, const float* bias, int B, int C, int OC) {
    if (B <= 0 || OC <= 0) return;
    if (!mlb_gemm_bf16_native()) {   // no AVX-512 BF16 (or forced off): fp32, as mlb_gemm_bf16 is then
        linear_forward(out, in, weight, bias, B, C, OC);
        return;
    }
    uint32_t* packed = C > 0 ? malloc(sizeof(uint32_t) * mlb_bf16_linear_weight_words(OC, C)) : NULL;
    if (packed) mlb_bf16_pack_linear_weight(packed, weight, OC, C);
    // without memory for the packed weight each task packs its panels: the same bits
    const mlb_bf16_operand w = {weight, 0, C, packed, NULL, NULL};
    linear_tiles(out, in, &w, bias, B, C, OC);
    free(packed);
}

mlb_status linear_forward_bf16_packed(float* out, const float* in, const uint32_t* weight, const float* bias, int B,
                                      int C, int OC) {
    if (B <= 0 || OC <= 0) return MLB_OK;
    if (!mlb_gemm_bf16_cpu_has())
        return mlb_fail(MLB_ERR_UNSUPPORTED, "linear: a weight packed for the bf16 kernel needs a CPU with AVX-512 BF16");
    const mlb_bf16_operand w = {NULL, 0, C, weight, NULL, NULL};
    linear_tiles(out, in, &w, bias, B, C, OC);
    return MLB_OK;
}

int mlb_bf16_packing_available(void) { return mlb_gemm_bf16_cpu_has(); }

size_t mlb_bf16_linear_weight_words(int OC, int C) { return mlb_gemm_bf16_packed_words(1, OC, C); }

int mlb_bf16_pack_linear_weight(uint32_t* out, const float* weight, int OC, int C) {
    if (!mlb_gemm_bf16_cpu_has()) return 0;
    const mlb_bf16_operand w = {weight, 0, C, NULL, NULL, NULL};
    mlb_gemm_bf16_pack(1, 1, OC, C, &w, out);
    return 1;
}
