// Internal: group norm over one group, 16 fp32 lanes at a time (groupnorm_avx512.c), for the float
// pass of groupnorm_forward / groupnorm_backward (conv_ops.c) when mlb_avx512_kernels() (avx512_gate.h).
#ifndef MATLABER_NN_GROUPNORM_AVX512_H
#define MATLABER_NN_GROUPNORM_AVX512_H

// One group of Cg channels of HW values: x, out [Cg, HW]; w, b its Cg channels' affine (or NULL);
// silu: apply SiLU after the affine (else identity). *mean, *rstd as groupnorm_forward's.
void mlb_groupnorm_forward_group(float* out, double* mean, double* rstd, const float* x, const float* w,
                                 const float* b, int Cg, int HW, float eps, int silu);

// Its backward given the forward's mean and rstd: part[cc] = {sum gy·xhat, sum gy} per channel
// (or NULL), and dx += the input gradient (dx NULL: sums only).
void mlb_groupnorm_backward_group(float* dx, double* part, const float* dout, const float* x, const float* w,
                                  const float* b, float mean, float rstd, int Cg, int HW, int silu);
#endif
