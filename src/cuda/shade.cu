// Split-sum shading forward and backward (shade.h mlb_shade_forward/backward) on the GPU: the
// pre-integrated cube maps and the LUT live in global memory (mlb_cuda_envlight), and each point
// runs the CPU's own maths (render/shade_math.h: seamless bilinear cube lookups, the mip blend, the
// LUT lookup, the Fresnel and the backward) in float instead of double.
#include <math.h>
#include <string.h>
#include "common.cuh"
#define MLB_SM_SINGLE 1
#include "render/shade_math.h"

// One thread per point: every output is written by one thread, no atomics.
__global__ void shade_forward_kernel(float* out, const float* kd, const float* ks, const float* kr, const float* n,
                                     const float* v, int N, sm_light L, int paper_fresnel) {
    for (int i = blockIdx.x * blockDim.x + threadIdx.x; i < N; i += gridDim.x * blockDim.x) {
        const size_t i3 = 3 * (size_t)i;
        sm_shade_point(&L, paper_fresnel, kd + i3, ks + i3, kr[i], n + i3, v + i3, out + i3, NULL, NULL, NULL, NULL,
                       NULL, NULL);
    }
}

// The backward of one point, accumulating into the non-NULL gradients.
__global__ void shade_backward_kernel(float* dkd, float* dks, float* dkr, float* dn, float* dv, const float* dout,
                                      const float* kd, const float* ks, const float* kr, const float* n, const float* v,
                                      int N, sm_light L, int paper_fresnel) {
    for (int i = blockIdx.x * blockDim.x + threadIdx.x; i < N; i += gridDim.x * blockDim.x) {
        const size_t i3 = 3 * (size_t)i;
        float o[3];
        sm_shade_point(&L, paper_fresnel, kd + i3, ks + i3, kr[i], n + i3, v + i3, o, dout + i3, dkd ? dkd + i3 : NULL,
                       dks ? dks + i3 : NULL, dkr ? dkr + i : NULL, dn ? dn + i3 : NULL, dv ? dv + i3 : NULL);
    }
}

// The light's device buffers as the shading maths sees them; (c, s) = (cos, -sin) of the rotation.
static sm_light make_dev_light(const mlb_cuda_envlight* light) {
    sm_light L;
    L.n_levels = light->n_levels;
    for (int l = 0; l < MLB_CUBE_MAX_LEVELS; l++) {
        L.size[l] = light->size[l];
        L.spec[l] = light->spec[l];
    }
    L.irr_size = light->irr_size;
    L.irr = light->irr;
    L.lut = light->lut;
    L.c = light->rot_cos;
    L.s = -light->rot_sin;
    return L;
}

extern "C" mlb_status mlb_cuda_envlight_upload(mlb_cuda_envlight* out, const mlb_envlight* light) {
    memset(out, 0, sizeof *out);
    if (!light || !light->irr || light->n_levels < 3 || light->n_levels > MLB_CUBE_MAX_LEVELS)
        return mlb_fail(MLB_ERR_ARG, "mlb_cuda_envlight_upload: the environment light is not built");
    const float* lut = mlb_splitsum_lut();
    if (!lut) return mlb_fail_context(MLB_ERR_NOMEM, "mlb_cuda_envlight_upload");
    mlb_status st = MLB_OK;
    out->n_levels = light->n_levels;
    for (int l = 0; l < light->n_levels && st == MLB_OK; l++) {
        size_t bytes = sizeof(float) * 6 * 3 * (size_t)light->size[l] * light->size[l];
        out->size[l] = light->size[l];
        st = mlb_cuda_malloc((void**)&out->spec[l], bytes);
        if (st == MLB_OK) st = mlb_cuda_copy_to_device(out->spec[l], light->spec[l], bytes);
    }
    out->irr_size = light->irr_size;
    size_t irr_bytes = sizeof(float) * 6 * 3 * (size_t)light->irr_size * light->irr_size;
    size_t lut_bytes = sizeof(float) * 2 * MLB_LUT_SIZE * MLB_LUT_SIZE;
    if (st == MLB_OK) st = mlb_cuda_malloc((void**)&out->irr, irr_bytes);
    if (st == MLB_OK) st = mlb_cuda_copy_to_device(out->irr, light->irr, irr_bytes);
    if (st == MLB_OK) st = mlb_cuda_malloc((void**)&out->lut, lut_bytes);
    if (st == MLB_OK) st = mlb_cuda_copy_to_device(out->lut, lut, lut_bytes);
    out->rot_cos = (float)cos((double)light->rotation);
    out->rot_sin = (float)sin((double)light->rotation);
    if (st != MLB_OK) {
        mlb_cuda_envlight_free(out);
        return mlb_fail_context(st, "mlb_cuda_envlight_upload");
    }
    return MLB_OK;
}

extern "C" void mlb_cuda_envlight_free(mlb_cuda_envlight* l) {
    if (!l) return;
    for (int i = 0; i < MLB_CUBE_MAX_LEVELS; i++) mlb_cuda_free(l->spec[i]);
    mlb_cuda_free(l->irr);
    mlb_cuda_free(l->lut);
    memset(l, 0, sizeof *l);
}

extern "C" mlb_status mlb_cuda_shade_forward(float* out, const float* kd, const float* ks, const float* kr, const float* n,
                                             const float* v, int N, const mlb_cuda_envlight* light, mlb_fresnel fresnel) {
    if (N < 0) return mlb_fail(MLB_ERR_ARG, "mlb_cuda_shade_forward: N = %d must be >= 0", N);
    if (!light || !light->irr || !light->lut || light->n_levels < 3)
        return mlb_fail(MLB_ERR_ARG, "mlb_cuda_shade_forward: the environment light is not uploaded");
    if (N == 0) return MLB_OK;
    sm_light L = make_dev_light(light);
    shade_forward_kernel<<<mlb_grid(N, 128), 128>>>(out, kd, ks, kr, n, v, N, L, fresnel == MLB_FRESNEL_PAPER);
    MLB_CUDA_LAUNCHED("shade_forward_kernel");
    return MLB_OK;
}

extern "C" mlb_status mlb_cuda_shade_backward(float* dkd, float* dks, float* dkr, float* dn, float* dv, const float* dout,
                                              const float* kd, const float* ks, const float* kr, const float* n,
                                              const float* v, int N, const mlb_cuda_envlight* light, mlb_fresnel fresnel) {
    if (N < 0) return mlb_fail(MLB_ERR_ARG, "mlb_cuda_shade_backward: N = %d must be >= 0", N);
    if (!light || !light->irr || !light->lut || light->n_levels < 3)
        return mlb_fail(MLB_ERR_ARG, "mlb_cuda_shade_backward: the environment light is not uploaded");
    if (N == 0 || (!dkd && !dks && !dkr && !dn && !dv)) return MLB_OK;
    sm_light L = make_dev_light(light);
    shade_backward_kernel<<<mlb_grid(N, 128), 128>>>(dkd, dks, dkr, dn, dv, dout, kd, ks, kr, n, v, N, L,
                                                     fresnel == MLB_FRESNEL_PAPER);
    MLB_CUDA_LAUNCHED("shade_backward_kernel");
    return MLB_OK;
}
