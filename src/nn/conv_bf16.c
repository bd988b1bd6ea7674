// Convolution on the bf16 GEMM kernel (gemm_bf16.c) as an "implicit GEMM": the kernel packs its B
// panels straight from the input image (mlb_bf16_operand.im2col), so no im2col matrix is written.
//
// Why: through an im2col buffer a 3x3 conv at 512² x 128 channels writes and reads back 1.2 GB of
// fp32 columns before the kernel packs them again, and the SD VAE's convs ran at 171 GFLOP/s where
// the kernel does 300+ on packed operands (docs/benchmarks.md).
//
//   out[OC, pixels] = W[OC, K] · col[K, pixels],  K = C·KH·KW
// The weight is packed once per call (every tile reads the same panels); the output pixels are cut
// into tiles of TILE_PIXELS, each one kernel call on one thread (its packed B block, TILE_PIXELS x
// 128 pairs, stays in L2). Each output element is one fp32 sum in k order exactly as in
// mlb_gemm_bf16 over an im2col buffer: the same bits, on any thread count.
//
// The input gradient of a stride-1 conv is itself such a conv: din[c] = sum_oc W[oc, c] flipped (*)
// dout[oc], with pads KH-1-pad_top etc. (the transposed conv's), so it runs here too instead of as a
// GEMM into a K x pixels buffer then a col2im scatter.
#include <stdint.h>
#include <stdlib.h>
#include "matlaber/conv_ops.h"   // the bf16 entry points defined here (conv2d_forward_bf16_packed, ..)
#include "matlaber/error.h"
#include "matlaber/nn.h"
#include "nn/conv_bf16.h"
#include "nn/gemm_bf16.h"

// Output pixels per task: its packed B block (TILE_PIXELS x 128 pairs x 4 bytes = 256 KB) and the
// fp32 tile sums of up to 256 channels stay in a Zen 4 core's 1 MB L2.
#define TILE_PIXELS 512

int conv2d_bf16_implicit_applies(const mlb_conv2d* cv, int input_grad) {
    if (!cv || !mlb_gemm_bf16_native()) return 0;
    if (mlb_conv2d_check(cv) != MLB_OK) {   // the caller's path reports it
        mlb_clear_error();
        return 0;
    }
    if (input_grad)
        return cv->stride_h == 1 && cv->stride_w == 1 && cv->pad_top < cv->KH && cv->pad_bottom < cv->KH &&
               cv->pad_left < cv->KW && cv->pad_right < cv->KW;
    return 1;
}

// Bytes of input images converted to bf16 at a time (mlb_gemm_bf16_image): all of a tiny-preset
// batch (4 x 32 x 130² values: 4.3 MB), a few of SD's 512² ones.
#define IMAGE_BUDGET ((size_t)32 << 20)

// The tiles: out (+)= W · im2col(in), W packed whole (w->packed). The input images are first
// rounded to bf16 and padded once (mlb_gemm_bf16_image): each value is read by KH·KW im2col rows,
// and from there a panel row is one load where the fp32 image took edge tests, masks and two
// conversions per row (the packing cost as much as the multiply on small convs, by perf). Images
// go in groups that fit IMAGE_BUDGET, each group one parallel region: convert, then the tiles.
static void conv_tiles(float* out, const float* in, const mlb_bf16_operand* w, const float* bias, const mlb_conv2d* cv,
                       int accumulate) {
    const int OC = cv->OC, K = cv->C * cv->KH * cv->KW, C = cv->C;
    const size_t plane = (size_t)mlb_conv2d_out_h(cv) * mlb_conv2d_out_w(cv);
    const size_t in_n = (size_t)cv->C * cv->H * cv->W, out_n = (size_t)OC * plane;
    const long tiles = (long)((plane + TILE_PIXELS - 1) / TILE_PIXELS);
    const size_t img_len = mlb_gemm_bf16_image_len(cv);
    size_t group = IMAGE_BUDGET / (img_len * sizeof(uint16_t));
    if (group < 1) group = 1;
    if (group > (size_t)cv->N) group = (size_t)cv->N;
    // without memory for it the panels come from the fp32 images: the same bits
    uint16_t* img16 = malloc(sizeof(uint16_t) * img_len * group);
    for (int n0 = 0; n0 < cv->N; n0 += (int)group) {
        const int nn = cv->N - n0 < (int)group ? cv->N - n0 : (int)group;
        const long tasks = (long)nn * tiles, convs = img16 ? (long)nn * C : 0;
#pragma omp parallel if (tasks > 1 || convs * (long)(in_n / C) >= 32768)
        {
#pragma omp for schedule(static)
            for (long t = 0; t < convs; t++)
                mlb_gemm_bf16_image(cv, in + (size_t)(n0 + t / C) * in_n, (int)(t % C), (int)(t % C) + 1,
                                    img16 + (size_t)(t / C) * img_len);
#pragma omp for schedule(dynamic)
            for (long t = 0; t < tasks; t++) {
                const int n = n0 + (int)(t / tiles);
                const size_t p0 = (size_t)(t % tiles) * TILE_PIXELS;
                const int np = plane - p0 < TILE_PIXELS ? (int)(plane - p0) : TILE_PIXELS;
                float* o = out + (size_t)n * out_n + p0;
                const mlb_bf16_operand col = {in + (size_t)n * in_n, p0, (int)plane, NULL, cv,
                                              img16 ? img16 + (size_t)(n - n0) * img_len : NULL};
                // the sums added to the bias (to out with accumulate) as over an im2col buffer
                if (accumulate) mlb_gemm_bf16_kernel(0, 0, OC, np, K, 1.0f, w, &col, 1.0f, o, (int)plane);
                else if (bias) mlb_gemm_bf16_kernel_bias(0, 0, OC, np, K, 1.0f, w, &col, 0.0f, bias, o, (int)plane);
                else mlb_gemm_bf16_kernel(0, 0, OC, np, K, 1.0f, w, &col, 0.0f, o, (int)plane);
            }
        }
    }
    free(img16);
}

mlb_status conv2d_bf16_implicit_forward(float* out, const float* in, const float* weight, const float* bias,
                                        const mlb_conv2d* cv, int accumulate) {
    MLB_TRY(mlb_conv2d_check(cv));
    if (!out || !in || !weight) return mlb_fail(MLB_ERR_ARG, "conv2d: NULL buffer");
    const int OC = cv->OC, K = cv->C * cv->KH * cv->KW;
    uint32_t* packed = malloc(sizeof(uint32_t) * mlb_gemm_bf16_packed_words(0, OC, K));
    mlb_bf16_operand w = {weight, 0, K, NULL, NULL, NULL};
    if (packed) mlb_gemm_bf16_pack(0, 0, OC, K, &w, packed);
    w.packed = packed;   // without memory for it each task packs its panels: the same bits
    conv_tiles(out, in, &w, bias, cv, accumulate);
    free(packed);
    return MLB_OK;
}

mlb_status conv2d_forward_bf16_packed(float* out, const float* in, const uint32_t* weight, const float* bias,
                                      const mlb_conv2d* cv) {
    MLB_TRY(mlb_conv2d_check(cv));
    if (!out || !in || !weight) return mlb_fail(MLB_ERR_ARG, "conv2d: NULL buffer");
    if (!mlb_gemm_bf16_cpu_has())
        return mlb_fail(MLB_ERR_UNSUPPORTED, "conv2d: a weight packed for the bf16 kernel needs a CPU with AVX-512 BF16");
    const mlb_bf16_operand w = {NULL, 0, cv->C * cv->KH * cv->KW, weight, NULL, NULL};
    conv_tiles(out, in, &w, bias, cv, 0);
    return MLB_OK;
}

size_t mlb_bf16_conv_weight_words(int OC, int K) { return mlb_gemm_bf16_packed_words(0, OC, K); }

int mlb_bf16_pack_conv_weight(uint32_t* out, const float* weight, int OC, int K) {
    if (!mlb_gemm_bf16_cpu_has()) return 0;
    const mlb_bf16_operand w = {weight, 0, K, NULL, NULL, NULL};
    mlb_gemm_bf16_pack(0, 0, OC, K, &w, out);
    return 1;
}

mlb_status conv2d_bf16_implicit_input_grad(float* din, const float* dout, const float* weight, const mlb_conv2d* cv) {
    MLB_TRY(mlb_conv2d_check(cv));
    if (!din || !dout || !weight) return mlb_fail(MLB_ERR_ARG, "conv2d backward: NULL buffer");
    const int C = cv->C, OC = cv->OC, KH = cv->KH, KW = cv->KW;
    float* flipped = malloc(sizeof(float) * (size_t)C * OC * KH * KW);   // [C, OC, KH, KW]
    if (!flipped) return mlb_fail(MLB_ERR_NOMEM, "conv2d backward (bf16): out of memory for the flipped weight");
    // written in order, in parallel over its rows (up to 30M values in the SD UNet)
#pragma omp parallel for schedule(static) if ((size_t)C * OC * KH * KW >= ((size_t)1 << 18))
    for (int c = 0; c < C; c++)
        for (int oc = 0; oc < OC; oc++)
            for (int i = 0; i < KH; i++)
                for (int j = 0; j < KW; j++)
                    flipped[(((size_t)c * OC + oc) * KH + i) * KW + j] =
                        weight[(((size_t)oc * C + c) * KH + (KH - 1 - i)) * KW + (KW - 1 - j)];
    const mlb_conv2d t = {cv->N, OC, mlb_conv2d_out_h(cv), mlb_conv2d_out_w(cv), C, KH, KW, 1, 1,
                          KH - 1 - cv->pad_top, KW - 1 - cv->pad_left, KH - 1 - cv->pad_bottom, KW - 1 - cv->pad_right};
    mlb_status st = conv2d_bf16_implicit_forward(din, dout, flipped, NULL, &t, 1);
    free(flipped);
    return st;
}
