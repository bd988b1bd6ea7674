// The conv descriptor's helpers (matlaber/conv_desc.h), compiled once: the float and double
// convolutions of conv_ops.c and the bf16 ones of conv_bf16.c / gemm_bf16.c all call these.
#include <stdint.h>
#include "matlaber/conv_desc.h"

mlb_conv2d mlb_conv2d_make(int N, int C, int H, int W, int OC, int K, int stride, int pad) {
    mlb_conv2d cv = {N, C, H, W, OC, K, K, stride, stride, pad, pad, pad, pad};
    return cv;
}

int mlb_conv2d_out_h(const mlb_conv2d* cv) {
    if (cv->stride_h < 1) return 0;
    int64_t span = (int64_t)cv->H + cv->pad_top + cv->pad_bottom - cv->KH;
    return span < 0 ? 0 : (int)(span / cv->stride_h + 1);
}

int mlb_conv2d_out_w(const mlb_conv2d* cv) {
    if (cv->stride_w < 1) return 0;
    int64_t span = (int64_t)cv->W + cv->pad_left + cv->pad_right - cv->KW;
    return span < 0 ? 0 : (int)(span / cv->stride_w + 1);
}

mlb_status mlb_conv2d_check(const mlb_conv2d* cv) {
    if (!cv) return mlb_fail(MLB_ERR_ARG, "conv2d: NULL descriptor");
    if (cv->N < 1 || cv->C < 1 || cv->H < 1 || cv->W < 1 || cv->OC < 1 || cv->KH < 1 || cv->KW < 1)
        return mlb_fail(MLB_ERR_ARG, "conv2d: bad shape: input [%d, %d, %d, %d], weight [%d, %d, %d, %d]", cv->N,
                        cv->C, cv->H, cv->W, cv->OC, cv->C, cv->KH, cv->KW);
    if (cv->stride_h < 1 || cv->stride_w < 1)
        return mlb_fail(MLB_ERR_ARG, "conv2d: stride %dx%d must be at least 1", cv->stride_h, cv->stride_w);
    if (cv->pad_top < 0 || cv->pad_left < 0 || cv->pad_bottom < 0 || cv->pad_right < 0)
        return mlb_fail(MLB_ERR_ARG, "conv2d: negative padding %d,%d,%d,%d (top, left, bottom, right)", cv->pad_top,
                        cv->pad_left, cv->pad_bottom, cv->pad_right);
    int64_t ph = (int64_t)cv->H + cv->pad_top + cv->pad_bottom, pw = (int64_t)cv->W + cv->pad_left + cv->pad_right;
    if (ph < cv->KH || pw < cv->KW)
        return mlb_fail(MLB_ERR_ARG, "conv2d: kernel %dx%d does not fit the padded input %lldx%lld (pad %d,%d,%d,%d)",
                        cv->KH, cv->KW, (long long)ph, (long long)pw, cv->pad_top, cv->pad_left, cv->pad_bottom,
                        cv->pad_right);
    int64_t lim = INT32_MAX;
    int64_t OH = mlb_conv2d_out_h(cv), OW = mlb_conv2d_out_w(cv);
    if ((int64_t)cv->C * cv->H * cv->W > lim || (int64_t)cv->OC * OH * OW > lim ||
        (int64_t)cv->C * cv->KH * cv->KW > lim / 4 || (int64_t)cv->OC * cv->C * cv->KH * cv->KW > lim)
        return mlb_fail(MLB_ERR_ARG, "conv2d: input [%d, %d, %d, %d] with a %dx%d kernel is too large (more than 2^31 "
                        "values per image)", cv->N, cv->C, cv->H, cv->W, cv->KH, cv->KW);
    return MLB_OK;
}
