// Transformer building blocks (llm.c style: plain functions over row-major buffers, shapes in the
// signature): layer norm forward/backward, multi-head self-attention forward (optionally causal,
// fused QKV or separate q/k/v), token + position embedding lookup. See docs/text_encoder.md.
//
// Every function exists twice from one source (src/nn/transformer_ops.c, an MLB_DUAL_SOURCE): float under the plain
// name and double under name_f64 (for finite-difference tests and reference computations).
// Results never depend on the thread count: every output value is computed by one thread in a
// fixed order. Backward functions ACCUMULATE (+=) into gradient buffers, any of which may be NULL.
#ifndef MATLABER_TRANSFORMER_OPS_H
#define MATLABER_TRANSFORMER_OPS_H
#include "matlaber/error.h"

// ---- layer norm over the last dimension ---------------------------------------------------------
// out[N,C] = (in - mean) * rstd * weight + bias, with mean and rstd = 1 / sqrt(var + eps) of each
// row (biased variance, two-pass, accumulated in double). weight/bias [C] may be NULL (1 / 0).
// mean/rstd [N] receive the statistics for the backward (may be NULL). out may alias in.
void layernorm_forward(float* out, float* mean, float* rstd, const float* in, const float* weight,
                       const float* bias, int N, int C, float eps);
void layernorm_forward_f64(double* out, double* mean, double* rstd, const double* in, const double* weight,
                           const double* bias, int N, int C, double eps);
// With xhat = (in - mean) * rstd and g = dout * weight:
//   din[N,C]  += rstd * (g - mean_c(g) - xhat * mean_c(g * xhat))
//   dweight[C] += sum_n dout * xhat,   dbias[C] += sum_n dout
// mean/rstd are the forward's (required); weight NULL means 1.
void layernorm_backward(float* din, float* dweight, float* dbias, const float* dout, const float* in,
                        const float* weight, const float* mean, const float* rstd, int N, int C);
void layernorm_backward_f64(double* din, double* dweight, double* dbias, const double* dout, const double* in,
                            const double* weight, const double* mean, const double* rstd, int N, int C);

// ---- multi-head scaled dot-product self-attention ------------------------------------------------
// NH heads of width hd = C / NH. For every batch b, head h and query t:
//   p[t, s] = softmax_s(q[b,t,h] . k[b,s,h] / sqrt(hd)),  s in [0, T) (s <= t when causal)
//   out[b, t, h*hd : (h+1)*hd] = sum_s p[t, s] v[b,s,h]
// q, k, v point at token (0, 0); consecutive tokens are `ld` values apart and head h starts at
// h*hd: ld = C for three separate [B,T,C] buffers, ld = 3C for a fused qkv [B,T,3C] with
// q = qkv, k = qkv + C, v = qkv + 2C. out [B,T,C] (row stride C) must not overlap q/k/v.
// att [B,NH,T,T] (may be NULL) receives p (exact zeros above the diagonal when causal).
// The softmax subtracts the row maximum (stable for any score size) and sums in double.
// OpenMP over B x NH. MLB_ERR_ARG for bad shapes (C not a multiple of NH, ld < C, ...),
// MLB_ERR_NOMEM when scratch cannot be allocated.
mlb_status attention_forward(float* out, float* att, const float* q, const float* k, const float* v, int ld,
                             int B, int T, int C, int NH, int causal);
mlb_status attention_forward_f64(double* out, double* att, const double* q, const double* k, const double* v,
                                 int ld, int B, int T, int C, int NH, int causal);

// ---- embedding lookup ---------------------------------------------------------------------------
// out[b,t,:] = wte[tokens[b,t], :] + wpe[t, :]   (wte [V,C]; wpe [>= T, C] or NULL for none).
// A token outside [0, V) is MLB_ERR_ARG: "token 49408 at [1, 5] is outside the vocabulary [0, 49408)";
// out is then unspecified.
mlb_status embedding_forward(float* out, const int* tokens, const float* wte, const float* wpe,
                             int B, int T, int C, int V);
mlb_status embedding_forward_f64(double* out, const int* tokens, const double* wte, const double* wpe,
                                 int B, int T, int C, int V);

#endif
