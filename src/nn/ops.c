// Ops with forward and backward (llm.c style): linear, activations, losses, Adam/AdamW.
// Written once over `real` and compiled twice (CMakeLists.txt: MLB_DUAL_SOURCES): float with the
// plain names, double with names suffixed _f64 (src/core/real.h). Every exported name goes
// through FN(...). Conventions (docs/ops.md):
//   - row-major buffers; a linear weight is [OC, C] (out, in) as in llm.c;
//   - backward ACCUMULATES (+=) into gradient buffers, and any gradient buffer may be NULL;
//   - results never depend on the number of threads: parallel loops are elementwise or split
//     over independent outputs, and every reduction runs in a fixed order (in double).
#include "matlaber/nn.h"
#include "core/real.h"
#include "nn/simd_rows.h"
#include <stdint.h>
#include <string.h>

// real.h has no erfc/expm1; they keep GELU and ELU accurate where 1 + erf and e^x - 1 cancel.
#ifdef MLB_F64
#define R_ERFC erfc
#define R_EXPM1 expm1
#else
#define R_ERFC erfcf
#define R_EXPM1 expm1f
#endif

// Elementwise loops go parallel only above this many values; below it the thread start-up
// costs more than the work.
#define OPS_PARALLEL_MIN 32768
// Values per call of a vectorised row kernel (nn/simd_rows.h) inside those loops.
#define ROW_BLOCK 4096

// ---------------------------------------------------------------------------------------------
// linear

// out[B,OC] = in[B,C] . weight[OC,C]^T + bias[OC]
static void FN(linear_forward_with)(FN(mlb_gemm_fn) gemm, real* out, const real* in, const real* weight,
                                    const real* bias, int B, int C, int OC) {
    if (B <= 0 || OC <= 0) return;
    // Start from the bias (or zero) and let GEMM add the product (beta = 1): one pass over out.
    for (int b = 0; b < B; b++) {
        real* o = out + (size_t)b * OC;
        for (int j = 0; j < OC; j++) o[j] = bias ? bias[j] : (real)0;
    }
    // C == 0 is a valid empty product, but BLAS rejects lda = 0, so skip the call.
    if (C <= 0) return;
    gemm(MLB_NOTRANS, MLB_TRANS, B, OC, C,
         (real)1, in, C, weight, C, (real)1, out, OC);
}

void FN(linear_forward)(real* out, const real* in, const real* weight, const real* bias, int B, int C, int OC) {
    FN(linear_forward_with)(GEMM, out, in, weight, bias, B, C, OC);
}

// dbias[OC] += sum_b dout[b, :]. Split over blocks of output columns, each summed over the batch in
// order b = 0..B-1 (in double), so the result is the same on any number of threads while the inner
// loop still walks dout row by row.
#define DBIAS_BLOCK 64
static void dbias_accumulate(real* dbias, const real* dout, int B, int OC) {
    int n_blocks = (OC + DBIAS_BLOCK - 1) / DBIAS_BLOCK;
#pragma omp parallel for schedule(static) if ((int64_t)B * OC >= OPS_PARALLEL_MIN)
    for (int blk = 0; blk < n_blocks; blk++) {
        int j0 = blk * DBIAS_BLOCK;
        int j1 = j0 + DBIAS_BLOCK < OC ? j0 + DBIAS_BLOCK : OC;
        double acc[DBIAS_BLOCK] = {0};
        for (int b = 0; b < B; b++) {
            const real* d = dout + (size_t)b * OC;
            for (int j = j0; j < j1; j++) acc[j - j0] += (double)d[j];
        }
        for (int j = j0; j < j1; j++) dbias[j] += (real)acc[j - j0];
    }
}

// din[B,C] += dout[B,OC] . weight[OC,C]; dweight[OC,C] += dout^T . in[B,C]; dbias[OC] += sum_b dout
static void FN(linear_backward_with)(FN(mlb_gemm_fn) gemm, real* din, real* dweight, real* dbias,
                                     const real* dout, const real* in, const real* weight, int B, int C, int OC) {
    // With B == 0 or OC == 0 every sum is empty: nothing is added. C == 0 leaves only dbias.
    if (B <= 0 || OC <= 0) return;
    if (C > 0) {
        if (din)
            gemm(MLB_NOTRANS, MLB_NOTRANS, B, C, OC,
                 (real)1, dout, OC, weight, C, (real)1, din, C);
        if (dweight)
            gemm(MLB_TRANS, MLB_NOTRANS, OC, C, B,
                 (real)1, dout, OC, in, C, (real)1, dweight, C);
    }
    if (dbias) dbias_accumulate(dbias, dout, B, OC);
}

void FN(linear_backward)(real* din, real* dweight, real* dbias, const real* dout, const real* in,
                         const real* weight, int B, int C, int OC) {
    FN(linear_backward_with)(GEMM, din, dweight, dbias, dout, in, weight, B, C, OC);
}

#ifndef MLB_F64
void linear_backward_bf16(float* din, float* dweight, float* dbias, const float* dout, const float* in,
                          const float* weight, int B, int C, int OC) {
    linear_backward_with(mlb_gemm_bf16, din, dweight, dbias, dout, in, weight, B, C, OC);
}
#endif

// ---------------------------------------------------------------------------------------------
// activations

// sigmoid and its derivatives, written so that nothing overflows and the tails keep their
// relative accuracy: sigma'(x) = e/(1+e)^2 with e = exp(-|x|) stays accurate where s(1-s) would
// round to 0 (x ~ 17 in float), and sigma''(x) = -sigma'(x) tanh(x/2).
static inline real sigmoid_r(real x) {
    if (x >= 0) return (real)1 / ((real)1 + R_EXP(-x));
    real e = R_EXP(x);
    return e / ((real)1 + e);
}
static inline real sigmoid_d1(real x) {
    real e = R_EXP(-R_FABS(x));
    real d = (real)1 + e;
    return e / (d * d);
}
static inline real sigmoid_d2(real x) { return -sigmoid_d1(x) * R_TANH((real)0.5 * x); }

// tanh'(x) = sech^2(x) = 4e/(1+e)^2 with e = exp(-2|x|): accurate in the tails, unlike 1 - t^2.
static inline real tanh_d1(real x) {
    real e = R_EXP((real)-2 * R_FABS(x));
    real d = (real)1 + e;
    return (real)4 * e / (d * d);
}

#define GELU_INV_SQRT2 ((real)0.70710678118654752440)
#define GELU_INV_SQRT_2PI ((real)0.39894228040143267794)
#define GELU_TANH_K ((real)0.79788456080286535588)   // sqrt(2/pi)
#define GELU_TANH_A ((real)0.044715)
#define QUICK_GELU_A ((real)1.702)
#define LEAKY_SLOPE ((real)0.01)

// Standard normal density and cdf. Phi(x) = erfc(-x/sqrt2)/2 equals (1 + erf(x/sqrt2))/2 but keeps
// its relative accuracy for x << 0 where 1 + erf cancels.
static inline real normal_pdf(real x) { return GELU_INV_SQRT_2PI * R_EXP((real)-0.5 * x * x); }
static inline real normal_cdf(real x) { return (real)0.5 * R_ERFC(-x * GELU_INV_SQRT2); }

// GELU (tanh form): 0.5 x (1 + tanh(u)), u = k (x + a x^3). Since 0.5 (1 + tanh(u)) = sigmoid(2u),
// f = x s(g) with g = 2u, which avoids the cancellation of 1 + tanh(u) for x << 0.
static inline real gelu_tanh_g(real x) { return (real)2 * GELU_TANH_K * (x + GELU_TANH_A * x * x * x); }
static inline real gelu_tanh_g1(real x) { return (real)2 * GELU_TANH_K * ((real)1 + (real)3 * GELU_TANH_A * x * x); }
static inline real gelu_tanh_g2(real x) { return (real)12 * GELU_TANH_K * GELU_TANH_A * x; }

// f(x)
real FN(mlb_act)(mlb_activation act, real x) {
    switch (act) {
    case MLB_ACT_IDENTITY: return x;
    case MLB_ACT_RELU: return x > 0 ? x : (real)0;
    case MLB_ACT_LEAKY_RELU: return x > 0 ? x : LEAKY_SLOPE * x;
    case MLB_ACT_SIGMOID: return sigmoid_r(x);
    case MLB_ACT_TANH: return R_TANH(x);
    case MLB_ACT_SILU: return x * sigmoid_r(x);
    // log(1 + e^x) = max(x, 0) + log1p(e^-|x|): no overflow for large x, no loss for x << 0.
    case MLB_ACT_SOFTPLUS: return (x > 0 ? x : (real)0) + R_LOG1P(R_EXP(-R_FABS(x)));
    case MLB_ACT_GELU: return x * normal_cdf(x);
    case MLB_ACT_GELU_TANH: return x * sigmoid_r(gelu_tanh_g(x));
    case MLB_ACT_QUICK_GELU: return x * sigmoid_r(QUICK_GELU_A * x);
    case MLB_ACT_ELU: return x > 0 ? x : R_EXPM1(x);
    default: return (real)NAN;   // not an activation: make it loud rather than plausible
    }
}

// f'(x). At the kinks x = 0 takes the x <= 0 branch: RELU'(0) = 0, LEAKY_RELU'(0) = 0.01,
// ELU'(0) = 1 (ELU' is continuous there).
real FN(mlb_act_d1)(mlb_activation act, real x) {
    switch (act) {
    case MLB_ACT_IDENTITY: return (real)1;
    case MLB_ACT_RELU: return x > 0 ? (real)1 : (real)0;
    case MLB_ACT_LEAKY_RELU: return x > 0 ? (real)1 : LEAKY_SLOPE;
    case MLB_ACT_SIGMOID: return sigmoid_d1(x);
    case MLB_ACT_TANH: return tanh_d1(x);
    case MLB_ACT_SILU: return sigmoid_r(x) + x * sigmoid_d1(x);
    case MLB_ACT_SOFTPLUS: return sigmoid_r(x);
    case MLB_ACT_GELU: return normal_cdf(x) + x * normal_pdf(x);
    case MLB_ACT_GELU_TANH: {
        // f' = s(g) + x s'(g) g'. Once s'(g) has underflowed the second term is 0; testing for that
        // keeps 0 * inf (g' overflows for |x| ~ 1e19 in float) from turning into NaN.
        real g = gelu_tanh_g(x), sp = sigmoid_d1(g);
        real r = sigmoid_r(g);
        if (sp != 0) r += x * sp * gelu_tanh_g1(x);
        return r;
    }
    case MLB_ACT_QUICK_GELU: {
        real z = QUICK_GELU_A * x;
        return sigmoid_r(z) + z * sigmoid_d1(z);
    }
    case MLB_ACT_ELU: return x > 0 ? (real)1 : R_EXP(x);
    default: return (real)NAN;
    }
}

// f''(x), for Jacobian-vector products through an activation. Piecewise-linear activations
// have f'' = 0 (the delta at the kink is dropped); ELU''(0) takes the x <= 0 branch (= 1).
real FN(mlb_act_d2)(mlb_activation act, real x) {
    switch (act) {
    case MLB_ACT_IDENTITY:
    case MLB_ACT_RELU:
    case MLB_ACT_LEAKY_RELU: return (real)0;
    case MLB_ACT_SIGMOID: return sigmoid_d2(x);
    case MLB_ACT_TANH: return (real)-2 * R_TANH(x) * tanh_d1(x);
    // (x s)'' = 2 s' + x s''
    case MLB_ACT_SILU: return (real)2 * sigmoid_d1(x) + x * sigmoid_d2(x);
    case MLB_ACT_SOFTPLUS: return sigmoid_d1(x);
    // (x Phi)'' = 2 phi + x phi' = phi (2 - x^2); once phi has underflowed that is 0 (and x^2
    // may have overflowed: 0 * inf would be NaN).
    case MLB_ACT_GELU: {
        real pdf = normal_pdf(x);
        return pdf != 0 ? pdf * ((real)2 - x * x) : (real)0;
    }
    case MLB_ACT_GELU_TANH: {
        // f = x s(g): f'' = 2 s'(g) g' + x (s''(g) g'^2 + s'(g) g''); zero once s'(g) underflows.
        real g = gelu_tanh_g(x), sp = sigmoid_d1(g);
        if (sp == 0) return (real)0;
        real g1 = gelu_tanh_g1(x);
        return (real)2 * sp * g1 + x * (sigmoid_d2(g) * g1 * g1 + sp * gelu_tanh_g2(x));
    }
    case MLB_ACT_QUICK_GELU: {
        // f = x s(a x): f'' = 2 a s'(ax) + a^2 x s''(ax) = a (2 s'(z) + z s''(z)), z = a x
        real z = QUICK_GELU_A * x;
        return QUICK_GELU_A * ((real)2 * sigmoid_d1(z) + z * sigmoid_d2(z));
    }
    case MLB_ACT_ELU: return x > 0 ? (real)0 : R_EXP(x);
    default: return (real)NAN;
    }
}

// out[n] = f(in[n]); out may alias in.
void FN(activation_forward)(real* out, const real* in, size_t n, mlb_activation act) {
#pragma omp parallel for schedule(static) if (n >= OPS_PARALLEL_MIN)
    for (size_t i = 0; i < n; i++) out[i] = FN(mlb_act)(act, in[i]);
}

// out = f(in), d1 = f'(in), d2 = f''(in) in one pass (d1, d2 may be NULL). The smooth activations a
// network trains with get a fused path that shares one exponential between the three values; the
// rest fall back to the scalar functions. Used by the MLP, which keeps d1 and d2 for its backward
// and Jacobian-vector passes instead of recomputing them.
// Values per block of the SiLU / sigmoid path below.
#define ACT_BLOCK 256

// SiLU or sigmoid over values [b, b + m) (m <= ACT_BLOCK): the exponentials e^-|x| as a row (float
// on a CPU with AVX2 or AVX-512: the softmax's exponential, mlb_exp_shifted_row, within 3e-7 of
// libm's; else libm one by one), then the arithmetic of the loop below over the block as SIMD (IEEE
// adds, multiplies, divides and selects lane by lane: the same values), the three results written
// where asked for. libm's expf was ~3% of a `tiny` generation (the material network's and the BRDF
// decoder's SiLU), the scalar division and tests more before that.
static void FN(sigmoid_family_block)(real* out, real* d1, real* d2, const real* in, size_t b, size_t m, int silu) {
    real e[ACT_BLOCK], f[ACT_BLOCK], g[ACT_BLOCK], h[ACT_BLOCK];
#ifndef MLB_F64
    const mlb_simd_level level = mlb_simd_kernels();
    if (level != MLB_SIMD_SCALAR) {
        for (size_t i = 0; i < m; i++) e[i] = -R_FABS(in[b + i]);
        mlb_exp_shifted_row(level, e, (int)m, 0.0f);   // e^min(-|x|, 0); a NaN's 1 is put right below
    } else
#endif
        for (size_t i = 0; i < m; i++) e[i] = R_EXP(-R_FABS(in[b + i]));
    if (silu) {
#pragma omp simd
        for (size_t i = 0; i < m; i++) {
            real x = in[b + i], inv = (real)1 / ((real)1 + e[i]), ei = e[i] * inv, pos = x >= 0;
            real s = pos ? inv : ei, sc = pos ? ei : inv;
            real ds = s * sc, dds = ds * (sc - s);
            f[i] = x * s;
            g[i] = s + x * ds;
            h[i] = (real)2 * ds + x * dds;
        }
    } else {
#pragma omp simd
        for (size_t i = 0; i < m; i++) {
            real x = in[b + i], inv = (real)1 / ((real)1 + e[i]), ei = e[i] * inv, pos = x >= 0;
            real s = pos ? inv : ei, sc = pos ? ei : inv;
            s = x == x ? s : x;   // sigma(NaN) is NaN (SiLU's x·s is already)
            real ds = s * sc;
            f[i] = s;
            g[i] = ds;
            h[i] = ds * (sc - s);
        }
    }
    memcpy(out + b, f, sizeof(real) * m);
    if (d1) memcpy(d1 + b, g, sizeof(real) * m);
    if (d2) memcpy(d2 + b, h, sizeof(real) * m);
}

void FN(activation_forward_derivs)(real* out, real* d1, real* d2, const real* in, size_t n, mlb_activation act) {
    if (act == MLB_ACT_SILU || act == MLB_ACT_SIGMOID) {
        const size_t blocks = (n + ACT_BLOCK - 1) / ACT_BLOCK;
#pragma omp parallel for schedule(static) if (n >= OPS_PARALLEL_MIN)
        for (size_t k = 0; k < blocks; k++) {
            const size_t b = k * ACT_BLOCK;
            FN(sigmoid_family_block)(out, d1, d2, in, b, n - b < ACT_BLOCK ? n - b : ACT_BLOCK, act == MLB_ACT_SILU);
        }
        return;
    }
#ifndef MLB_F64
    const mlb_simd_level level = mlb_simd_kernels();
    if ((act == MLB_ACT_RELU || act == MLB_ACT_IDENTITY) && level != MLB_SIMD_SCALAR) {   // the loop's bits below
        const size_t blocks = (n + ROW_BLOCK - 1) / ROW_BLOCK;
#pragma omp parallel for schedule(static) if (n >= OPS_PARALLEL_MIN)
        for (size_t b = 0; b < blocks; b++) {
            const size_t i = b * ROW_BLOCK, m = n - i < ROW_BLOCK ? n - i : ROW_BLOCK;
            mlb_relu_row(level, out + i, d1 ? d1 + i : NULL, d2 ? d2 + i : NULL, in + i, m, act == MLB_ACT_RELU);
        }
        return;
    }
#endif
#pragma omp parallel for schedule(static) if (n >= OPS_PARALLEL_MIN)
    for (size_t i = 0; i < n; i++) {
        real x = in[i], f, g, h;
        if (act == MLB_ACT_SILU || act == MLB_ACT_SIGMOID) {
            // s and 1 - s from e = exp(-|x|), both accurate in either tail
            real e = R_EXP(-R_FABS(x)), inv = (real)1 / ((real)1 + e);
            real s = x >= 0 ? inv : e * inv, sc = x >= 0 ? e * inv : inv;   // sigma(x), 1 - sigma(x)
            real ds = s * sc;                                                 // sigma'
            real dds = ds * (sc - s);                                         // sigma''
            if (act == MLB_ACT_SIGMOID) { f = s; g = ds; h = dds; }
            else { f = x * s; g = s + x * ds; h = (real)2 * ds + x * dds; }
        } else if (act == MLB_ACT_TANH) {
            real t = R_TANH(x);
            f = t; g = (real)1 - t * t; h = (real)-2 * t * g;
        } else if (act == MLB_ACT_IDENTITY) {
            f = x; g = 1; h = 0;
        } else if (act == MLB_ACT_RELU) {
            f = x > 0 ? x : 0; g = x > 0 ? 1 : 0; h = 0;
        } else {
            f = FN(mlb_act)(act, x); g = FN(mlb_act_d1)(act, x); h = FN(mlb_act_d2)(act, x);
        }
        out[i] = f;
        if (d1) d1[i] = g;
        if (d2) d2[i] = h;
    }
}

// din[n] += dout[n] * f'(in[n]), in = the pre-activation saved by forward.
void FN(activation_backward)(real* din, const real* dout, const real* in, size_t n,
                             mlb_activation act) {
    if (!din) return;
#pragma omp parallel for schedule(static) if (n >= OPS_PARALLEL_MIN)
    for (size_t i = 0; i < n; i++) din[i] += dout[i] * FN(mlb_act_d1)(act, in[i]);
}

// ---------------------------------------------------------------------------------------------
// losses. Sums run sequentially in double: a fixed order (the same result on any thread count)
// and no float drift over large n. These are O(n) next to the GEMMs, so a serial loop is fine.
// An empty input has loss 0 (not 0/0).

// mse = mean_i (pred_i - target_i)^2
real FN(mse_forward)(const real* pred, const real* target, size_t n) {
    if (n == 0) return (real)0;
    double sum = 0;
    for (size_t i = 0; i < n; i++) {
        double d = (double)pred[i] - (double)target[i];
        sum += d * d;
    }
    return (real)(sum / (double)n);
}

// dpred += dloss * 2 (pred - target) / n
void FN(mse_backward)(real* dpred, const real* pred, const real* target, size_t n, real dloss) {
    if (!dpred || n == 0) return;
    real scale = (real)(2.0 * (double)dloss / (double)n);
#pragma omp parallel for schedule(static) if (n >= OPS_PARALLEL_MIN)
    for (size_t i = 0; i < n; i++) dpred[i] += scale * (pred[i] - target[i]);
}

// l1 = mean_i |pred_i - target_i|
real FN(l1_forward)(const real* pred, const real* target, size_t n) {
    if (n == 0) return (real)0;
    double sum = 0;
    for (size_t i = 0; i < n; i++) sum += fabs((double)pred[i] - (double)target[i]);
    return (real)(sum / (double)n);
}

// dpred += dloss * sign(pred - target) / n, with sign(0) = 0 (the subgradient at the kink)
void FN(l1_backward)(real* dpred, const real* pred, const real* target, size_t n, real dloss) {
    if (!dpred || n == 0) return;
    real scale = (real)((double)dloss / (double)n);
#pragma omp parallel for schedule(static) if (n >= OPS_PARALLEL_MIN)
    for (size_t i = 0; i < n; i++) {
        real d = pred[i] - target[i];
        dpred[i] += d > 0 ? scale : (d < 0 ? -scale : (real)0);
    }
}

// KL(N(mu, e^logvar) || N(0, 1)) = 0.5 sum_d (mu^2 + e^logvar - 1 - logvar), averaged over B rows.
// mu, logvar: [B, D]. e^lv - 1 is computed as expm1(lv): near lv = 0 (the posterior matching the
// prior) e^lv - 1 - lv would otherwise lose most of its digits.
real FN(kl_normal_forward)(const real* mu, const real* logvar, int B, int D) {
    if (B <= 0 || D <= 0) return (real)0;
    size_t n = (size_t)B * D;
    double sum = 0;
    for (size_t i = 0; i < n; i++) {
        double m = mu[i], lv = logvar[i];
        sum += m * m + expm1(lv) - lv;
    }
    return (real)(0.5 * sum / (double)B);
}

// dmu += dloss * mu / B; dlogvar += dloss * 0.5 (e^logvar - 1) / B
void FN(kl_normal_backward)(real* dmu, real* dlogvar, const real* mu, const real* logvar,
                            int B, int D, real dloss) {
    if (B <= 0 || D <= 0) return;
    size_t n = (size_t)B * D;
    real scale = (real)((double)dloss / (double)B);
    real half_scale = (real)(0.5 * (double)dloss / (double)B);
    if (dmu) {
#pragma omp parallel for schedule(static) if (n >= OPS_PARALLEL_MIN)
        for (size_t i = 0; i < n; i++) dmu[i] += scale * mu[i];
    }
    if (dlogvar) {
#pragma omp parallel for schedule(static) if (n >= OPS_PARALLEL_MIN)
        for (size_t i = 0; i < n; i++) dlogvar[i] += half_scale * R_EXPM1(logvar[i]);
    }
}

// ---------------------------------------------------------------------------------------------
// optimiser

// One Adam / AdamW step t (1-based) over n parameters; m, v hold the first and second moments
// (zero before step 1).
//   decoupled = 0 (Adam + L2):  g += wd p
//   decoupled = 1 (AdamW):      p *= 1 - lr wd       (before the Adam step, as in PyTorch)
//   m = b1 m + (1-b1) g;  v = b2 v + (1-b2) g^2;  p -= lr (m / (1-b1^t)) / (sqrt(v / (1-b2^t)) + eps)
// The bias corrections are computed in double (b2^t for b2 = 0.999 is far from 1 only after
// thousands of steps; in float 1 - b2^t at t = 1 would keep just a few digits).
void FN(adam_update)(real* params, const real* grads, real* m, real* v, size_t n,
                     const mlb_adam_config* cfg, long t) {
    double lr = cfg->lr, b1 = cfg->beta1, b2 = cfg->beta2, wd = cfg->weight_decay;
    double bc1 = 1.0 - pow(b1, (double)t);
    double bc2 = 1.0 - pow(b2, (double)t);
    // p -= lr m / bc1 / (sqrt(v / bc2) + eps) rewritten with the per-step constants folded:
    // p -= step (m / (sqrt(v) inv_sqrt_bc2 + eps)).
    real step = (real)(lr / bc1);
    real inv_sqrt_bc2 = (real)(1.0 / sqrt(bc2));
    real eps = (real)cfg->eps;
    real beta1 = (real)b1, beta2 = (real)b2;
    real one_minus_b1 = (real)(1.0 - b1), one_minus_b2 = (real)(1.0 - b2);
    // decoupled: a multiply by one factor, so a parameter with g = 0 (and m = v = 0) shrinks by
    // exactly (1 - lr wd) per step.
    real decay = cfg->decoupled ? (real)(1.0 - lr * wd) : (real)1;
    real l2 = cfg->decoupled ? (real)0 : (real)wd;
#ifndef MLB_F64
    const mlb_simd_level level = mlb_simd_kernels();
    if (level != MLB_SIMD_SCALAR) {   // the same bits, 8 or 16 at a time (the dense hash tables' steps)
        const mlb_adam_consts k = {l2, decay, beta1, one_minus_b1, beta2, one_minus_b2, inv_sqrt_bc2, eps, step};
        const size_t blocks = (n + ROW_BLOCK - 1) / ROW_BLOCK;
#pragma omp parallel for schedule(static) if (n >= OPS_PARALLEL_MIN)
        for (size_t b = 0; b < blocks; b++) {
            const size_t i = b * ROW_BLOCK;
            mlb_adam_row(level, params + i, grads + i, m + i, v + i, n - i < ROW_BLOCK ? n - i : ROW_BLOCK, &k);
        }
        return;
    }
#endif
#pragma omp parallel for schedule(static) if (n >= OPS_PARALLEL_MIN)
    for (size_t i = 0; i < n; i++) {
        real p = params[i];
        real g = grads[i] + l2 * p;
        p *= decay;
        real mi = beta1 * m[i] + one_minus_b1 * g;
        real vi = beta2 * v[i] + one_minus_b2 * g * g;
        m[i] = mi;
        v[i] = vi;
        params[i] = p - step * (mi / (R_SQRT(vi) * inv_sqrt_bc2 + eps));
    }
}
