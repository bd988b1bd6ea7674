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

#endif
