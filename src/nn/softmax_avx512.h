// Internal: the attention's row softmax in 16 fp32 lanes (softmax_avx512.c), for the CPU's bf16
// attention (attention_bf16.c) and the float pass of sdpa_forward (conv_ops.c) when
// mlb_avx512_kernels() (avx512_gate.h).
#ifndef MATLABER_NN_SOFTMAX_AVX512_H
#define MATLABER_NN_SOFTMAX_AVX512_H

// Row p[0..n) (n >= 1): p <- e^(p - max p) by the vectorised exp of avx512_math.h; returns the max,
// *sum = the sum of the new p (fp32, 16 partial sums added in a fixed order). Call only where
// mlb_avx512_kernels() says the CPU has AVX-512.
float mlb_softmax_row_avx512(float* p, int n, float* sum);
#endif
