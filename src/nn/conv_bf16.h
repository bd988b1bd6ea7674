// Internal: 2-D convolution on the bf16 GEMM kernel without an im2col buffer (conv_bf16.c), run by
// conv2d_forward_bf16(_stored) and conv2d_backward_bf16 (conv_ops.c) where it applies.
#ifndef MATLABER_NN_CONV_BF16_H
#define MATLABER_NN_CONV_BF16_H
#include "matlaber/conv_desc.h"

// Whether it applies: a valid conv on a CPU with AVX-512 BF16 (a 1x1 conv too: then the "im2col" is
// the image itself, and the same path gives the same bits as conv2d_forward_bf16_packed); for the
// input gradient also stride 1 with each pad below the kernel's size.
int conv2d_bf16_implicit_applies(const mlb_conv2d* cv, int input_grad);

// out = conv(in, weight) + bias (accumulate 0) or out += conv(in, weight) (accumulate 1, no bias).
mlb_status conv2d_bf16_implicit_forward(float* out, const float* in, const float* weight, const float* bias,
                                        const mlb_conv2d* cv, int accumulate);

// din += d/d(in) of a stride-1 conv: the conv of dout with the weight flipped and transposed.
mlb_status conv2d_bf16_implicit_input_grad(float* din, const float* dout, const float* weight, const mlb_conv2d* cv);
#endif
