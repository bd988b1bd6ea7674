// The 2-D convolution's descriptor (mlb_conv2d), its output size and its check: what conv_ops.h's
// convolutions, the bf16 kernel's im2col operand (src/nn/gemm_bf16.c, conv_bf16.c) and the CUDA
// convolutions all read, in a file of their own (src/nn/conv_desc.c) so that none of them depends
// on another for it.
#ifndef MATLABER_CONV_DESC_H
#define MATLABER_CONV_DESC_H
#include "matlaber/error.h"

// ---- 2-D convolution (cross-correlation, as torch.nn.Conv2d with groups = 1, dilation 1) --------
// in [N, C, H, W], weight [OC, C, KH, KW], bias [OC] (may be NULL), out [N, OC, OH, OW] with
//   OH = (H + pad_top + pad_bottom - KH) / stride_h + 1      (integer division, floor)
//   OW = (W + pad_left + pad_right - KW) / stride_w + 1
//   out[n,o,y,x] = bias[o] + sum_{c,i,j} weight[o,c,i,j] * in[n, c, y*stride_h - pad_top + i,
//                                                               x*stride_w - pad_left + j]
// with zeros outside the input. Per-side padding makes the SD VAE's downsample, torch's
// F.pad(x, (0, 1, 0, 1)) then a stride-2 3x3 conv, one call: pad_top 0, pad_left 0,
// pad_bottom 1, pad_right 1.
typedef struct {
    int N, C, H, W;                                 // input [N, C, H, W]; N, C, H, W >= 1
    int OC, KH, KW;                                 // weight [OC, C, KH, KW]; all >= 1
    int stride_h, stride_w;                         // >= 1
    int pad_top, pad_left, pad_bottom, pad_right;   // zero padding per side, >= 0
} mlb_conv2d;

// Square kernel K, stride s and the same padding p on every side (torch's Conv2d(C, OC, K, s, p)).
mlb_conv2d mlb_conv2d_make(int N, int C, int H, int W, int OC, int K, int stride, int pad);
int mlb_conv2d_out_h(const mlb_conv2d* cv);   // OH as above (<= 0 when the kernel does not fit)
int mlb_conv2d_out_w(const mlb_conv2d* cv);   // OW
// MLB_OK, or MLB_ERR_ARG with a message such as
//   "conv2d: kernel 3x3 does not fit the padded input 1x1 (pad 0,0,0,0)"
// (negative or zero sizes, strides < 1, negative padding, OH or OW < 1, more than 2^31 values).
mlb_status mlb_conv2d_check(const mlb_conv2d* cv);

#endif
