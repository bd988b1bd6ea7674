// Ops with forward and backward, llm.c style: plain functions over buffers, shapes in the
// signature, backward ACCUMULATES (+=) into gradient buffers (any of which may be NULL).
// Every declaration exists twice: float (plain name) and double (name_f64); see src/core/real.h.
#ifndef MATLABER_NN_H
#define MATLABER_NN_H
#include <stddef.h>
#include <stdint.h>
#include "matlaber/error.h"

typedef enum {
    MLB_ACT_IDENTITY = 0,
    MLB_ACT_RELU,
    MLB_ACT_LEAKY_RELU,   // slope 0.01 for x < 0
    MLB_ACT_SIGMOID,
    MLB_ACT_TANH,
    MLB_ACT_SILU,         // x * sigmoid(x)
    MLB_ACT_SOFTPLUS,     // log(1 + e^x), computed stably
    MLB_ACT_GELU,         // exact: 0.5 x (1 + erf(x / sqrt 2))
    MLB_ACT_GELU_TANH,    // tanh approximation
    MLB_ACT_QUICK_GELU,   // x * sigmoid(1.702 x) (CLIP)
    MLB_ACT_ELU,          // alpha 1
    MLB_ACT_COUNT
} mlb_activation;

const char* mlb_activation_name(mlb_activation act);
int mlb_activation_parse(const char* name, mlb_activation* out);   // 0 on success

// Transpose flags of mlb_gemm.
enum { MLB_NOTRANS = 0, MLB_TRANS = 1 };

// Adam / AdamW. decoupled = 0: Adam with L2 (g += wd * p); decoupled = 1: AdamW (p -= lr * wd * p).
typedef struct {
    double lr, beta1, beta2, eps, weight_decay;
    int decoupled;
} mlb_adam_config;
mlb_adam_config mlb_adamw_default(double lr);   // betas (0.9, 0.999), eps 1e-8, wd 0.01, decoupled

#define MLB_REAL float
#define MLB_FN(name) name
#include "matlaber/nn_api.inc"
#undef MLB_REAL
#undef MLB_FN
#define MLB_REAL double
#define MLB_FN(name) name##_f64
#include "matlaber/nn_api.inc"
#undef MLB_REAL
#undef MLB_FN

// ---- bf16 GEMM (float only): mlb_gemm's contract, with op(A) and op(B) rounded to bf16 (nearest
// even; denormals read as zero) and the products summed in fp32 (AVX-512 BF16, src/nn/gemm_bf16.c).
// Bitwise the same on any thread count (mlb_gemm's shards). Where the CPU lacks AVX-512 BF16, or
// $MATLABER_CPU_BF16 is 0/off, it is mlb_gemm (fp32), and says so once (info log).
// Error against the exact product of the fp32 inputs: about 2^-8 · sqrt(K) relative to the sum of
// |terms| (each operand carries up to 2^-9 relative rounding; tests/test_gemm_bf16.c).
void mlb_gemm_bf16(int trans_a, int trans_b, int M, int N, int K, float alpha, const float* A, int lda,
                   const float* B, int ldb, float beta, float* C, int ldc);
// 1 when mlb_gemm_bf16 runs the bf16 kernel here, 0 when it falls back to fp32.
int mlb_gemm_bf16_native(void);
// For tests: on = 1 forces the fp32 fallback, 0 uses the kernel where the CPU has it.
void mlb_gemm_bf16_force_fallback(int on);
// 1 when the bf16 kernel runs on Intel AMX tiles (src/nn/gemm_amx.c: the CPU has AMX-BF16 and
// $MATLABER_CPU_AMX is not 0/off), 0 on AVX-512 BF16 alone. Other bits than AVX-512 BF16's, the same
// bound. For tests: off = 1 turns AMX off, 0 back on where the CPU has it; operands packed before
// (mlb_bf16_pack_*) must be packed again after either (their A layout follows it).
int mlb_gemm_bf16_amx(void);
void mlb_gemm_bf16_force_amx_off(int off);
// linear_forward / linear_backward with their GEMMs on the bf16 kernel (the bias sums stay fp32/double).
void linear_forward_bf16(float* out, const float* in, const float* weight, const float* bias, int B, int C, int OC);
// linear_forward_bf16 with the weight [OC, C] packed once for the kernel (a frozen model's: the UNet
// loaded with bf16_weights) by mlb_bf16_pack_linear_weight into mlb_bf16_linear_weight_words(OC, C)
// words (bf16 values in the kernel's panel layout, about half of fp32): the same bits, without
// packing per call. The packing returns 0 (writing nothing), the linear MLB_ERR_UNSUPPORTED, on a
// CPU without AVX-512 BF16.
int mlb_bf16_packing_available(void);   // whether the packers (and packed ops) run: AVX-512 BF16
size_t mlb_bf16_linear_weight_words(int OC, int C);
int mlb_bf16_pack_linear_weight(uint32_t* out, const float* weight, int OC, int C);
mlb_status linear_forward_bf16_packed(float* out, const float* in, const uint32_t* weight, const float* bias, int B,
                                      int C, int OC);
void linear_backward_bf16(float* din, float* dweight, float* dbias, const float* dout, const float* in,
                          const float* weight, int B, int C, int OC);

#endif
