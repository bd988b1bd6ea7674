// Split-sum shading forward (shade.h mlb_shade_forward) on the GPU: the pre-integrated cube maps
// and the LUT live in global memory (mlb_cuda_envlight), each point does the CPU's seamless
// bilinear cube lookups (src/render/cubemap.c), the mip blend and the LUT lookup
// (src/render/splitsum_lut.c), in float instead of double.
#include <math.h>
#include <string.h>
#include "common.cuh"

// Face f: major axis MA (sign SG), fx along axis IU (sign SU), fy along axis IV (sign SV).
__constant__ int c_MA[6] = {0, 0, 1, 1, 2, 2};
__constant__ float c_SG[6] = {1, -1, 1, -1, 1, -1};
__constant__ int c_IU[6] = {2, 2, 0, 0, 0, 0};
__constant__ float c_SU[6] = {-1, 1, 1, 1, 1, -1};
__constant__ int c_IV[6] = {1, 1, 2, 2, 1, 1};
__constant__ float c_SV[6] = {-1, -1, 1, -1, -1, -1};

struct dev_light {
    int n_levels;
    int size[MLB_CUBE_MAX_LEVELS];
    const float* spec[MLB_CUBE_MAX_LEVELS];
    int irr_size;
    const float* irr;
    const float* lut;
    float rc, rs;   // cos, sin of the rotation
};

__device__ __forceinline__ int dir_face(const float d[3]) {
    float ax = fabsf(d[0]), ay = fabsf(d[1]), az = fabsf(d[2]);
    if (ax >= ay && ax >= az) return d[0] >= 0 ? 0 : 1;
    if (ay >= az) return d[1] >= 0 ? 2 : 3;
    return d[2] >= 0 ? 4 : 5;
}

__device__ __forceinline__ const float* texel(const float* cube, int n, int f, int x, int y) {
    return cube + (((size_t)f * n + y) * n + x) * 3;
}

// (x, y) with exactly one coordinate one step outside [0, n): the texel across that edge.
__device__ const float* texel_across(const float* cube, int n, int f, int x, int y) {
    int out_x = x < 0 || x >= n;
    float fx = out_x ? (x < 0 ? -1.0f : 1.0f) : 2.0f * (x + 0.5f) / n - 1.0f;
    float fy = out_x ? 2.0f * (y + 0.5f) / n - 1.0f : (y < 0 ? -1.0f : 1.0f);
    float p[3];
    p[c_MA[f]] = c_SG[f];
    p[c_IU[f]] = c_SU[f] * fx;
    p[c_IV[f]] = c_SV[f] * fy;
    int ax = out_x ? c_IU[f] : c_IV[f];
    int g = 2 * ax + (p[ax] < 0);
    int tx = (int)floorf((c_SU[g] * p[c_IU[g]] + 1) * 0.5f * n), ty = (int)floorf((c_SV[g] * p[c_IV[g]] + 1) * 0.5f * n);
    tx = min(max(tx, 0), n - 1);
    ty = min(max(ty, 0), n - 1);
    return texel(cube, n, g, tx, ty);
}

__device__ void fetch(const float* cube, int n, int f, int x, int y, float out[3]) {
    int ix = x >= 0 && x < n, iy = y >= 0 && y < n;
    const float* t;
    if (ix && iy) t = texel(cube, n, f, x, y);
    else if (ix || iy) t = texel_across(cube, n, f, x, y);
    else {   // a cube corner: the mean of the three texels there
        int cx = min(max(x, 0), n - 1), cy = min(max(y, 0), n - 1);
        const float* a = texel(cube, n, f, cx, cy);
        const float* b = texel_across(cube, n, f, x, cy);
        const float* c = texel_across(cube, n, f, cx, y);
        for (int k = 0; k < 3; k++) out[k] = (a[k] + b[k] + c[k]) / 3.0f;
        return;
    }
    out[0] = t[0], out[1] = t[1], out[2] = t[2];
}

// Seamless bilinear lookup in one cube level; optional Jacobian d rgb[c] / d dir[k] (CPU:
// mlb_cube_sample).
__device__ void cube_sample(const float* cube, int n, const float d[3], float rgb[3], float (*jac)[3] = NULL) {
    int f = dir_face(d);
    float m = fabsf(d[c_MA[f]]);
    float fx = c_SU[f] * d[c_IU[f]] / m, fy = c_SV[f] * d[c_IV[f]] / m;
    if (!(m > 0) || !(fabsf(fx) <= 1) || !(fabsf(fy) <= 1)) {   // the zero vector, NaN or Inf
        rgb[0] = rgb[1] = rgb[2] = 0;
        if (jac)
            for (int c = 0; c < 3; c++) jac[c][0] = jac[c][1] = jac[c][2] = 0;
        return;
    }
    float px = (fx + 1) * 0.5f * n - 0.5f, py = (fy + 1) * 0.5f * n - 0.5f;
    float x0f = floorf(px), y0f = floorf(py), tx = px - x0f, ty = py - y0f;
    int x0 = (int)x0f, y0 = (int)y0f;
    float t00[3], t01[3], t10[3], t11[3];
    fetch(cube, n, f, x0, y0, t00);
    fetch(cube, n, f, x0 + 1, y0, t01);
    fetch(cube, n, f, x0, y0 + 1, t10);
    fetch(cube, n, f, x0 + 1, y0 + 1, t11);
    for (int c = 0; c < 3; c++) rgb[c] = (1 - ty) * ((1 - tx) * t00[c] + tx * t01[c]) + ty * ((1 - tx) * t10[c] + tx * t11[c]);
    if (!jac) return;
    // d px / d dir: px = (SU d[IU] / |d[MA]| + 1) n/2 - 1/2
    float h = 0.5f * n, sg = d[c_MA[f]] >= 0 ? 1.0f : -1.0f;
    float dpx[3] = {0, 0, 0}, dpy[3] = {0, 0, 0};
    dpx[c_IU[f]] = h * c_SU[f] / m;
    dpx[c_MA[f]] = -h * fx * sg / m;
    dpy[c_IV[f]] = h * c_SV[f] / m;
    dpy[c_MA[f]] = -h * fy * sg / m;
    for (int c = 0; c < 3; c++) {
        float gx = (1 - ty) * (t01[c] - t00[c]) + ty * (t11[c] - t10[c]);
        float gy = (1 - tx) * (t10[c] - t00[c]) + tx * (t11[c] - t01[c]);
        for (int k = 0; k < 3; k++) jac[c][k] = gx * dpx[k] + gy * dpy[k];
    }
}

__device__ __forceinline__ void to_local(const dev_light& L, const float d[3], float out[3]) {
    float c = L.rc, s = -L.rs;
    out[0] = c * d[0] + s * d[2];
    out[1] = d[1];
    out[2] = -s * d[0] + c * d[2];
}

__device__ void jac_to_world(float (*jac)[3], float c, float s) {   // jac_world = jac_local R
    for (int ch = 0; ch < 3; ch++) {
        float j0 = jac[ch][0], j2 = jac[ch][2];
        jac[ch][0] = j0 * c - j2 * s;
        jac[ch][2] = j0 * s + j2 * c;
    }
}

__device__ float envlight_mip(int n_levels, float r, float* dm = NULL) {
    float l2 = (float)(n_levels - 2), m, d;
    if (!(r > 0.08f)) m = 0, d = 0;
    else if (r < 0.5f) m = (r - 0.08f) / 0.42f * l2, d = l2 / 0.42f;
    else m = ((r >= 1 ? 1.0f : r) - 0.5f) / 0.5f + l2, d = r < 1 ? 2.0f : 0.0f;
    if (dm) *dm = d;
    return m;
}

// Prefiltered radiance around world direction dir (CPU: mlb_envlight_specular), optional Jacobians.
__device__ void envlight_specular(const dev_light& L, const float dir[3], float roughness, float rgb[3],
                                  float (*jac_dir)[3] = NULL, float* jac_r = NULL) {
    float d[3], dm;
    to_local(L, dir, d);
    float m = envlight_mip(L.n_levels, roughness, &dm);
    int m0 = (int)floorf(m);
    m0 = min(max(m0, 0), L.n_levels - 1);
    int m1 = m0 + 1 < L.n_levels ? m0 + 1 : m0;
    float t = m0 == m1 ? 0.0f : m - m0;
    float v0[3], v1[3], j0[3][3], j1[3][3];
    cube_sample(L.spec[m0], L.size[m0], d, v0, jac_dir ? j0 : NULL);
    if (m1 != m0) cube_sample(L.spec[m1], L.size[m1], d, v1, jac_dir ? j1 : NULL);
    else v1[0] = v0[0], v1[1] = v0[1], v1[2] = v0[2];
    for (int c = 0; c < 3; c++) rgb[c] = (1 - t) * v0[c] + t * v1[c];
    if (jac_r)
        for (int c = 0; c < 3; c++) jac_r[c] = m1 != m0 ? (v1[c] - v0[c]) * dm : 0.0f;
    if (jac_dir) {
        for (int c = 0; c < 3; c++)
            for (int k = 0; k < 3; k++) jac_dir[c][k] = m1 != m0 ? (1 - t) * j0[c][k] + t * j1[c][k] : j0[c][k];
        jac_to_world(jac_dir, L.rc, -L.rs);
    }
}

// CPU: mlb_splitsum_lookup, optional derivatives with respect to n.v and roughness.
__device__ void splitsum_lookup(const float* lut, float nv, float roughness, float b[2], float* db_dnv = NULL,
                                float* db_dr = NULL) {
    const int n = MLB_LUT_SIZE;
    if (!(nv >= 1e-4f)) nv = 1e-4f;
    float px = nv * n - 0.5f, py = roughness * n - 0.5f;
    int gx = px > 0 && px < n - 1, gy = py > 0 && py < n - 1;
    if (!(px > 0)) px = 0;
    if (px > n - 1) px = (float)(n - 1);
    if (!(py > 0)) py = 0;
    if (py > n - 1) py = (float)(n - 1);
    int x0 = min((int)px, n - 2), y0 = min((int)py, n - 2);
    float tx = px - x0, ty = py - y0;
    const float* r0 = lut + ((size_t)y0 * n + x0) * 2;
    const float* r1 = r0 + (size_t)n * 2;
    for (int k = 0; k < 2; k++) {
        float t00 = r0[k], t01 = r0[2 + k], t10 = r1[k], t11 = r1[2 + k];
        b[k] = (1 - ty) * ((1 - tx) * t00 + tx * t01) + ty * ((1 - tx) * t10 + tx * t11);
        if (db_dnv) db_dnv[k] = gx ? ((1 - ty) * (t01 - t00) + ty * (t11 - t10)) * n : 0.0f;
        if (db_dr) db_dr[k] = gy ? ((1 - tx) * (t10 - t00) + tx * (t11 - t01)) * n : 0.0f;
    }
}

__global__ void shade_forward_kernel(float* out, const float* kd, const float* ks, const float* kr, const float* n,
                                     const float* v, int N, dev_light L, int paper_fresnel) {
    for (int i = blockIdx.x * blockDim.x + threadIdx.x; i < N; i += gridDim.x * blockDim.x) {
        float nn[3], vv[3];
        for (int k = 0; k < 3; k++) nn[k] = n[3 * (size_t)i + k], vv[k] = v[3 * (size_t)i + k];
        const float rough = kr[i];
        float nv = nn[0] * vv[0] + nn[1] * vv[1] + nn[2] * vv[2];
        float nvc = nv < 1e-4f ? 1e-4f : nv > 1 ? 1.0f : nv;
        float r[3];
        for (int k = 0; k < 3; k++) r[k] = 2 * nv * nn[k] - vv[k];
        float irr[3], spec[3], B[2], nl[3];
        to_local(L, nn, nl);
        cube_sample(L.irr, L.irr_size, nl, irr);
        envlight_specular(L, r, rough, spec);
        splitsum_lookup(L.lut, nv, rough, B);
        float x = 1 - nvc, x5 = x * x * x * x * x;
        for (int c = 0; c < 3; c++) {
            float f0 = ks[3 * (size_t)i + c], F = f0;
            if (paper_fresnel && 1 - rough > f0) F = f0 + (1 - rough - f0) * x5;
            out[3 * (size_t)i + c] = kd[3 * (size_t)i + c] * irr[c] + (F * B[0] + B[1]) * spec[c];
        }
    }
}

// The backward of one point (CPU: shade_point with g), accumulating into the non-NULL gradients.
// One thread per point: every output is written by one thread, no atomics.
__global__ void shade_backward_kernel(float* dkd, float* dks, float* dkr, float* dn, float* dv, const float* dout,
                                      const float* kd, const float* ks, const float* kr, const float* n, const float* v,
                                      int N, dev_light L, int paper_fresnel) {
    for (int i = blockIdx.x * blockDim.x + threadIdx.x; i < N; i += gridDim.x * blockDim.x) {
        const size_t i3 = 3 * (size_t)i;
        float nn[3], vv[3], g[3];
        for (int k = 0; k < 3; k++) nn[k] = n[i3 + k], vv[k] = v[i3 + k], g[k] = dout[i3 + k];
        const float rough = kr[i];
        float nv = nn[0] * vv[0] + nn[1] * vv[1] + nn[2] * vv[2];
        float nvc = nv < 1e-4f ? 1e-4f : nv > 1 ? 1.0f : nv, dnvc = nv > 1e-4f && nv < 1 ? 1.0f : 0.0f;
        float r[3];
        for (int k = 0; k < 3; k++) r[k] = 2 * nv * nn[k] - vv[k];
        float irr[3], spec[3], jirr[3][3], jsd[3][3], jsr[3], B[2], dBnv[2], dBr[2], nl[3];
        to_local(L, nn, nl);
        cube_sample(L.irr, L.irr_size, nl, irr, jirr);
        jac_to_world(jirr, L.rc, -L.rs);
        envlight_specular(L, r, rough, spec, jsd, jsr);
        splitsum_lookup(L.lut, nv, rough, B, dBnv, dBr);
        float x = 1 - nvc, x5 = x * x * x * x * x, dx5 = -5 * x * x * x * x * dnvc;
        float d_r[3] = {0, 0, 0}, d_kr = 0, d_nv = 0, dB0 = 0, dB1 = 0, d_n[3] = {0, 0, 0};
        for (int c = 0; c < 3; c++) {
            float f0 = ks[i3 + c], F = f0, dF_f0 = 1, dF_kr = 0, dF_nv = 0;
            if (paper_fresnel && 1 - rough > f0) {
                F = f0 + (1 - rough - f0) * x5;
                dF_f0 = 1 - x5;
                dF_kr = -x5;
                dF_nv = (1 - rough - f0) * dx5;
            }
            float sfac = F * B[0] + B[1], gc = g[c];
            if (dkd) dkd[i3 + c] += gc * irr[c];
            float dirr = gc * kd[i3 + c], dspec = gc * sfac, dS = gc * spec[c], dF = dS * B[0];
            for (int k = 0; k < 3; k++) {
                d_n[k] += dirr * jirr[c][k];
                d_r[k] += dspec * jsd[c][k];
            }
            d_kr += dspec * jsr[c] + dF * dF_kr;
            dB0 += dS * F;
            dB1 += dS;
            if (dks) dks[i3 + c] += dF * dF_f0;
            d_nv += dF * dF_nv;
        }
        d_nv += dB0 * dBnv[0] + dB1 * dBnv[1];
        d_kr += dB0 * dBr[0] + dB1 * dBr[1];
        if (dkr) dkr[i] += d_kr;
        float rn = d_r[0] * nn[0] + d_r[1] * nn[1] + d_r[2] * nn[2];   // r = 2 (n.v) n - v
        for (int k = 0; k < 3; k++) {
            if (dn) dn[i3 + k] += d_n[k] + 2 * vv[k] * rn + 2 * nv * d_r[k] + d_nv * vv[k];
            if (dv) dv[i3 + k] += 2 * nn[k] * rn - d_r[k] + d_nv * nn[k];
        }
    }
}

static dev_light make_dev_light(const mlb_cuda_envlight* light) {
    dev_light L;
    L.n_levels = light->n_levels;
    for (int l = 0; l < MLB_CUBE_MAX_LEVELS; l++) {
        L.size[l] = light->size[l];
        L.spec[l] = light->spec[l];
    }
    L.irr_size = light->irr_size;
    L.irr = light->irr;
    L.lut = light->lut;
    L.rc = light->rot_cos;
    L.rs = light->rot_sin;
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
    dev_light L = make_dev_light(light);
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
    dev_light L = make_dev_light(light);
    shade_backward_kernel<<<mlb_grid(N, 128), 128>>>(dkd, dks, dkr, dn, dv, dout, kd, ks, kr, n, v, N, L,
                                                     fresnel == MLB_FRESNEL_PAPER);
    MLB_CUDA_LAUNCHED("shade_backward_kernel");
    return MLB_OK;
}
