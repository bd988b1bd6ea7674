// Internal: the CPU's vectorised fp32 row kernels (simd_rows.inc, compiled as simd_avx512.c and
// simd_avx2.c) and the one switch that picks them (simd_gate.c), for the float pass of group norm
// and of the attention's softmax (conv_ops.c), for the bf16 attention (attention_bf16.c), and for
// Adam and the ReLU / identity activations (ops.c).
#ifndef MATLABER_NN_SIMD_ROWS_H
#define MATLABER_NN_SIMD_ROWS_H
#include <stddef.h>

#if defined(__x86_64__) && defined(__GNUC__) && (__GNUC__ >= 10 || defined(__clang__))
#define MLB_SIMD_X86 1
#endif

typedef enum { MLB_SIMD_SCALAR = 0, MLB_SIMD_AVX2 = 1, MLB_SIMD_AVX512 = 2 } mlb_simd_level;

// The widest kernels this CPU runs: AVX-512 F/BW/VL/DQ, else AVX2 with FMA, else the scalar loops;
// capped by $MATLABER_CPU_AVX512=0 (at AVX2) and $MATLABER_CPU_AVX2=0 (at scalar), read once, and
// by mlb_simd_force.
mlb_simd_level mlb_simd_kernels(void);
// Tests: cap the level at `level` (a lower one where the CPU lacks it), or -1 for the default again.
void mlb_simd_force(int level);
const char* mlb_simd_name(mlb_simd_level level);   // "scalar", "AVX2", "AVX-512"

// One group of Cg channels of HW values: x, out [Cg, HW]; w, b its Cg channels' affine (or NULL);
// silu: SiLU after the affine (else identity). *mean, *rstd as groupnorm_forward's. Runs the kernel
// of `level` (not scalar).
void mlb_groupnorm_forward_group(mlb_simd_level level, float* out, double* mean, double* rstd, const float* x,
                                 const float* w, const float* b, int Cg, int HW, float eps, int silu);

// Its backward given the forward's mean and rstd: part[cc] = {sum gy·xhat, sum gy} per channel
// (or NULL), and dx += the input gradient (dx NULL: sums only).
void mlb_groupnorm_backward_group(mlb_simd_level level, float* dx, double* part, const float* dout, const float* x,
                                  const float* w, const float* b, float mean, float rstd, int Cg, int HW, int silu);

// Row p[0..n) (n >= 1): p <- e^(p - max p); returns the max, *sum = the sum of the new p (fp32, one
// partial sum per lane added in a fixed order).
float mlb_softmax_row(mlb_simd_level level, float* p, int n, float* sum);

// GEGLU over one row of n: out = a · GELU(gate) (exact GELU, x Φ(x)), and its backward that adds
// dout · GELU(gate) to da and dout · a · GELU'(gate) to dgate. Φ from a fit of erfc (fractional
// error < 1.2e-7; simd_rows.inc), not libm's erfcf.
void mlb_geglu_row(mlb_simd_level level, float* out, const float* a, const float* gate, int n);
void mlb_geglu_backward_row(mlb_simd_level level, float* da, float* dgate, const float* dout, const float* a,
                            const float* gate, int n);

// One Adam step over n values (ops.c's adam_update): the step's constants folded as there, and the
// loop's operations in its order with no fused multiply-add, so the bits are the scalar loop's.
typedef struct {
    float l2, decay, beta1, one_minus_b1, beta2, one_minus_b2, inv_sqrt_bc2, eps, step;
} mlb_adam_consts;
void mlb_adam_row(mlb_simd_level level, float* params, const float* grads, float* m, float* v, size_t n,
                  const mlb_adam_consts* k);

// ReLU (relu = 1) or the identity over n values, with f' where d1 is not NULL and f'' = 0 where d2
// is not NULL: the bits of ops.c's per-value loop (x > 0 ? x : 0; a NaN gives 0).
void mlb_relu_row(mlb_simd_level level, float* out, float* d1, float* d2, const float* in, size_t n, int relu);

// y += x over n values, the scalar loop's bits (additions are per value); y may be x.
void mlb_add_row(mlb_simd_level level, float* y, const float* x, size_t n);

// One row of layer norm's float pass (transformer_ops.c): the mean and variance in double as the
// group norm's (the lanes' sums, then their sum), xhat and the affine in fp32; w, b, mean, rstd may be
// NULL; o may be x.
void mlb_layernorm_row(mlb_simd_level level, float* o, float* mean, float* rstd, const float* x, const float* w,
                       const float* b, int C, float eps);

// The attention backward's rows (conv_ops.c): p <- e^min(p - c, 0) (the exponential as the softmax
// row's, not libm's), and g <- p (g - d) scale (the scalar loop's bits).
void mlb_exp_shifted_row(mlb_simd_level level, float* p, int n, float c);
void mlb_softmax_grad_row(mlb_simd_level level, float* g, const float* p, int n, float d, float scale);

#ifdef MLB_SIMD_X86
// The kernels themselves (call only where mlb_simd_kernels() is at least their level).
void mlb_groupnorm_forward_group_avx512(float* out, double* mean, double* rstd, const float* x, const float* w,
                                        const float* b, int Cg, int HW, float eps, int silu);
void mlb_groupnorm_forward_group_avx2(float* out, double* mean, double* rstd, const float* x, const float* w,
                                      const float* b, int Cg, int HW, float eps, int silu);
void mlb_groupnorm_backward_group_avx512(float* dx, double* part, const float* dout, const float* x, const float* w,
                                         const float* b, float mean, float rstd, int Cg, int HW, int silu);
void mlb_groupnorm_backward_group_avx2(float* dx, double* part, const float* dout, const float* x, const float* w,
                                       const float* b, float mean, float rstd, int Cg, int HW, int silu);
float mlb_softmax_row_avx512(float* p, int n, float* sum);
float mlb_softmax_row_avx2(float* p, int n, float* sum);
void mlb_geglu_row_avx512(float* out, const float* a, const float* gate, int n);
void mlb_geglu_row_avx2(float* out, const float* a, const float* gate, int n);
void mlb_geglu_backward_row_avx512(float* da, float* dgate, const float* dout, const float* a, const float* gate, int n);
void mlb_geglu_backward_row_avx2(float* da, float* dgate, const float* dout, const float* a, const float* gate, int n);
void mlb_adam_row_avx512(float* params, const float* grads, float* m, float* v, size_t n, const mlb_adam_consts* k);
void mlb_adam_row_avx2(float* params, const float* grads, float* m, float* v, size_t n, const mlb_adam_consts* k);
void mlb_relu_row_avx512(float* out, float* d1, float* d2, const float* in, size_t n, int relu);
void mlb_relu_row_avx2(float* out, float* d1, float* d2, const float* in, size_t n, int relu);
void mlb_add_row_avx512(float* y, const float* x, size_t n);
void mlb_add_row_avx2(float* y, const float* x, size_t n);
void mlb_layernorm_row_avx512(float* o, float* mean, float* rstd, const float* x, const float* w, const float* b, int C,
                              float eps);
void mlb_layernorm_row_avx2(float* o, float* mean, float* rstd, const float* x, const float* w, const float* b, int C,
                            float eps);
void mlb_exp_shifted_row_avx512(float* p, int n, float c);
void mlb_exp_shifted_row_avx2(float* p, int n, float c);
void mlb_softmax_grad_row_avx512(float* g, const float* p, int n, float d, float scale);
void mlb_softmax_grad_row_avx2(float* g, const float* p, int n, float d, float scale);
#endif
#endif
