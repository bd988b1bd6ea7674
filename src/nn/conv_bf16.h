// Internal: 2-D convolution on the bf16 GEMM kernel without an im2col buffer (conv_bf16.c), run by
// conv2d_forward_bf16(_stored) and conv2d_backward_bf16 (conv_ops.c) where it applies.
#ifndef MATLABER_NN_CONV_BF16_H
#define MATLABER_NN_CONV_BF16_H
#include "matlaber/conv_ops.h"

// Whether it applies: a valid conv that is not a plain GEMM (1x1, stride 1, no padding) on a CPU
// with AVX-512 BF16; for the input gradient also stride 1 with each pad below the kernel's size.
int conv2d_bf16_implicit_applies(const mlb_conv2d* cv, int input_grad);

// out = conv(in, weight) + bias (accumulate 0) or out += conv(in, weight) (accumulate 1, no bias).
// weight is fp32 or, with weight_bf16, uint16_t bf16 values [OC, C, KH, KW].
mlb_status conv2d_bf16_implicit_forward(float* out, const float* in, const void* weight, int weight_bf16,
                                        const float* bias, const mlb_conv2d* cv, int accumulate);

// din += d/d(in) of a stride-1 conv: the conv of dout with the weight flipped and transposed.
mlb_status conv2d_bf16_implicit_input_grad(float* din, const float* dout, const float* weight, const mlb_conv2d* cv);
#endif
