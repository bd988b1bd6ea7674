// Elementwise activations f and f' (nn_api.inc), the CPU's formulas (src/nn/ops.c) in float.
#include <math.h>
#include "common.cuh"
#include "act.cuh"

template <int WITH_D1>
__global__ void act_forward_kernel(float* out, float* d1, const float* in, size_t n, mlb_activation act) {
    for (size_t i = (size_t)blockIdx.x * blockDim.x + threadIdx.x; i < n; i += (size_t)gridDim.x * blockDim.x) {
        float x = in[i];
        if (WITH_D1 && d1) d1[i] = dev_act_d1(act, x);
        out[i] = dev_act(act, x);
    }
}

__global__ void act_backward_kernel(float* din, const float* dout, const float* in, size_t n, mlb_activation act) {
    for (size_t i = (size_t)blockIdx.x * blockDim.x + threadIdx.x; i < n; i += (size_t)gridDim.x * blockDim.x)
        din[i] += dout[i] * dev_act_d1(act, in[i]);
}

static mlb_status check_act(const char* fn, mlb_activation act) {
    if ((int)act < 0 || act >= MLB_ACT_COUNT) return mlb_fail(MLB_ERR_ARG, "%s: unknown activation %d", fn, (int)act);
    return MLB_OK;
}

extern "C" mlb_status mlb_cuda_activation_forward(float* out, const float* in, size_t n, mlb_activation act) {
    MLB_TRY(check_act("mlb_cuda_activation_forward", act));
    if (!n) return MLB_OK;
    act_forward_kernel<0><<<mlb_grid(n, 256), 256>>>(out, NULL, in, n, act);
    MLB_CUDA_LAUNCHED("act_forward_kernel");
    return MLB_OK;
}

extern "C" mlb_status mlb_cuda_activation_forward_d1(float* out, float* d1, const float* in, size_t n, mlb_activation act) {
    MLB_TRY(check_act("mlb_cuda_activation_forward_d1", act));
    if (!n) return MLB_OK;
    act_forward_kernel<1><<<mlb_grid(n, 256), 256>>>(out, d1, in, n, act);
    MLB_CUDA_LAUNCHED("act_forward_kernel<d1>");
    return MLB_OK;
}

extern "C" mlb_status mlb_cuda_activation_backward(float* din, const float* dout, const float* in, size_t n,
                                                   mlb_activation act) {
    MLB_TRY(check_act("mlb_cuda_activation_backward", act));
    if (!n || !din) return MLB_OK;
    act_backward_kernel<<<mlb_grid(n, 256), 256>>>(din, dout, in, n, act);
    MLB_CUDA_LAUNCHED("act_backward_kernel");
    return MLB_OK;
}
