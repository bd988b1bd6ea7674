// Private to src/cuda: the activations of src/nn/ops.c as device functions (same formulas, float),
// shared by the elementwise kernels and the fused group norm.
#ifndef MLB_CUDA_ACT_CUH
#define MLB_CUDA_ACT_CUH
#include <math.h>
extern "C" {
#include "matlaber/nn.h"
}

__device__ __forceinline__ float dev_sigmoid(float x) {
    if (x >= 0) return 1.0f / (1.0f + expf(-x));
    float e = expf(x);
    return e / (1.0f + e);
}
__device__ __forceinline__ float dev_sigmoid_d1(float x) {
    float e = expf(-fabsf(x)), d = 1.0f + e;
    return e / (d * d);
}
__device__ __forceinline__ float dev_tanh_d1(float x) {
    float e = expf(-2.0f * fabsf(x)), d = 1.0f + e;
    return 4.0f * e / (d * d);
}
#define DEV_INV_SQRT2 0.70710678118654752440f
#define DEV_INV_SQRT_2PI 0.39894228040143267794f
#define DEV_GELU_TANH_K 0.79788456080286535588f
#define DEV_GELU_TANH_A 0.044715f
#define DEV_QUICK_GELU_A 1.702f
#define DEV_LEAKY_SLOPE 0.01f
__device__ __forceinline__ float dev_normal_pdf(float x) { return DEV_INV_SQRT_2PI * expf(-0.5f * x * x); }
__device__ __forceinline__ float dev_normal_cdf(float x) { return 0.5f * erfcf(-x * DEV_INV_SQRT2); }
__device__ __forceinline__ float dev_gelu_tanh_g(float x) { return 2.0f * DEV_GELU_TANH_K * (x + DEV_GELU_TANH_A * x * x * x); }
__device__ __forceinline__ float dev_gelu_tanh_g1(float x) {
    return 2.0f * DEV_GELU_TANH_K * (1.0f + 3.0f * DEV_GELU_TANH_A * x * x);
}

__device__ __forceinline__ float dev_act(mlb_activation act, float x) {
    switch (act) {
    case MLB_ACT_IDENTITY: return x;
    case MLB_ACT_RELU: return x > 0 ? x : 0.0f;
    case MLB_ACT_LEAKY_RELU: return x > 0 ? x : DEV_LEAKY_SLOPE * x;
    case MLB_ACT_SIGMOID: return dev_sigmoid(x);
    case MLB_ACT_TANH: return tanhf(x);
    case MLB_ACT_SILU: return x * dev_sigmoid(x);
    case MLB_ACT_SOFTPLUS: return (x > 0 ? x : 0.0f) + log1pf(expf(-fabsf(x)));
    case MLB_ACT_GELU: return x * dev_normal_cdf(x);
    case MLB_ACT_GELU_TANH: return x * dev_sigmoid(dev_gelu_tanh_g(x));
    case MLB_ACT_QUICK_GELU: return x * dev_sigmoid(DEV_QUICK_GELU_A * x);
    case MLB_ACT_ELU: return x > 0 ? x : expm1f(x);
    default: return NAN;
    }
}

__device__ __forceinline__ float dev_act_d1(mlb_activation act, float x) {
    switch (act) {
    case MLB_ACT_IDENTITY: return 1.0f;
    case MLB_ACT_RELU: return x > 0 ? 1.0f : 0.0f;
    case MLB_ACT_LEAKY_RELU: return x > 0 ? 1.0f : DEV_LEAKY_SLOPE;
    case MLB_ACT_SIGMOID: return dev_sigmoid_d1(x);
    case MLB_ACT_TANH: return dev_tanh_d1(x);
    case MLB_ACT_SILU: return dev_sigmoid(x) + x * dev_sigmoid_d1(x);
    case MLB_ACT_SOFTPLUS: return dev_sigmoid(x);
    case MLB_ACT_GELU: return dev_normal_cdf(x) + x * dev_normal_pdf(x);
    case MLB_ACT_GELU_TANH: {
        float g = dev_gelu_tanh_g(x), sp = dev_sigmoid_d1(g), r = dev_sigmoid(g);
        if (sp != 0) r += x * sp * dev_gelu_tanh_g1(x);
        return r;
    }
    case MLB_ACT_QUICK_GELU: {
        float z = DEV_QUICK_GELU_A * x;
        return dev_sigmoid(z) + z * dev_sigmoid_d1(z);
    }
    case MLB_ACT_ELU: return x > 0 ? 1.0f : expf(x);
    default: return NAN;
    }
}

// The group norm's fused activation (src/nn/conv_ops.c gn_act): SiLU as y / (1 + e^-y).
__device__ __forceinline__ float dev_gn_act(mlb_activation act, float y) {
    if (act == MLB_ACT_IDENTITY) return y;
    if (act == MLB_ACT_SILU) return y / (1.0f + expf(-y));
    return dev_act(act, y);
}
#endif
