// Multiresolution hash encoding on the GPU: the contract of hashgrid_forward/backward
// (hashgrid.h). The cell position uses the CPU's float operations without FMA contraction
// (__fmul_rn / __fadd_rn), so every corner index and weight is bitwise the CPU's.
#include "common.cuh"

#define HG_MAXL MLB_HASHGRID_MAX_LEVELS
#define HG_MAXF MLB_HASHGRID_MAX_FEATURES

typedef struct {
    int L, F, D;
    float scale[HG_MAXL];
    uint32_t res[HG_MAXL], size[HG_MAXL];
    int dense[HG_MAXL];
    unsigned long long offset[HG_MAXL];   // first table entry of level l
} hg_layout;   // passed by value (kernel parameter space)

static mlb_status make_layout(const mlb_hashgrid* g, hg_layout* lay) {
    if (!g || g->cfg.n_levels < 1 || g->cfg.n_levels > HG_MAXL || g->cfg.n_features < 1 || g->cfg.n_features > HG_MAXF)
        return mlb_fail(MLB_ERR_ARG, "CUDA hash grid: the grid is not initialised (hashgrid_init)");
    lay->L = g->cfg.n_levels;
    lay->F = g->cfg.n_features;
    lay->D = g->out_dim;
    for (int l = 0; l < lay->L; l++) {
        lay->scale[l] = (float)g->scale[l];
        lay->res[l] = g->res[l];
        lay->size[l] = g->level_size[l];
        lay->dense[l] = g->dense[l];
        lay->offset[l] = g->offset[l];
    }
    return MLB_OK;
}

struct hg_corners {
    uint32_t idx[8];
    float w[8];
    float t[3];
};

__device__ __forceinline__ void hg_level_corners(const hg_layout& g, int l, const float* x, hg_corners& c) {
    const float s = g.scale[l];
    uint32_t base[3];
#pragma unroll
    for (int d = 0; d < 3; d++) {
        float xd = x[d];
        xd = xd >= 0 ? (xd > 1 ? 1.0f : xd) : 0.0f;   // clamp; NaN reads corner 0
        float p = __fadd_rn(__fmul_rn(s, xd), 0.5f);
        float fl = floorf(p);
        base[d] = (uint32_t)fl;
        c.t[d] = __fsub_rn(p, fl);
    }
    const uint32_t size = g.size[l];
    if (g.dense[l]) {
        const uint64_t r = g.res[l], b0 = base[0] + r * (base[1] + r * base[2]);
#pragma unroll
        for (int k = 0; k < 8; k++) {
            uint64_t i = b0 + (k & 1) + ((k >> 1) & 1) * r + ((k >> 2) & 1) * r * r;
            c.idx[k] = i < size ? (uint32_t)i : (uint32_t)(i % size);
        }
    } else {
        const uint32_t prime[3] = {1u, 2654435761u, 805459861u};
        uint32_t h[3][2];
#pragma unroll
        for (int d = 0; d < 3; d++) { h[d][0] = base[d] * prime[d]; h[d][1] = (base[d] + 1) * prime[d]; }
        const int pow2 = (size & (size - 1)) == 0;
#pragma unroll
        for (int k = 0; k < 8; k++) {
            uint32_t v = h[0][k & 1] ^ h[1][(k >> 1) & 1] ^ h[2][(k >> 2) & 1];
            c.idx[k] = pow2 ? v & (size - 1) : v % size;
        }
    }
#pragma unroll
    for (int k = 0; k < 8; k++) {
        float a = (k & 1) ? c.t[0] : __fsub_rn(1.0f, c.t[0]);
        float b = ((k >> 1) & 1) ? c.t[1] : __fsub_rn(1.0f, c.t[1]);
        float e = ((k >> 2) & 1) ? c.t[2] : __fsub_rn(1.0f, c.t[2]);
        c.w[k] = __fmul_rn(__fmul_rn(a, b), e);
    }
}

// One thread per (point, level); consecutive threads take consecutive points of one level, so a
// warp reads one level's table.
__global__ void hg_forward_kernel(hg_layout g, const float* params, float* out, const float* x, int N) {
    size_t total = (size_t)N * g.L;
    for (size_t j = (size_t)blockIdx.x * blockDim.x + threadIdx.x; j < total; j += (size_t)gridDim.x * blockDim.x) {
        int l = (int)(j / N), i = (int)(j % N);
        hg_corners c;
        hg_level_corners(g, l, x + 3 * (size_t)i, c);
        const float* table = params + g.offset[l] * g.F;
        float acc[HG_MAXF];
        for (int f = 0; f < g.F; f++) acc[f] = 0.0f;
#pragma unroll
        for (int k = 0; k < 8; k++) {
            const float* e = table + (size_t)c.idx[k] * g.F;
            for (int f = 0; f < g.F; f++) acc[f] = __fadd_rn(acc[f], __fmul_rn(c.w[k], e[f]));
        }
        for (int f = 0; f < g.F; f++) out[(size_t)i * g.D + l * g.F + f] = acc[f];
    }
}

// dparams: one thread per (point, level), atomicAdd to the 8 corners.
__global__ void hg_backward_params_kernel(hg_layout g, float* dparams, const float* dout, const float* x, int N) {
    size_t total = (size_t)N * g.L;
    for (size_t j = (size_t)blockIdx.x * blockDim.x + threadIdx.x; j < total; j += (size_t)gridDim.x * blockDim.x) {
        int l = (int)(j / N), i = (int)(j % N);
        hg_corners c;
        hg_level_corners(g, l, x + 3 * (size_t)i, c);
        float* table = dparams + g.offset[l] * g.F;
        const float* go = dout + (size_t)i * g.D + l * g.F;
        float gof[HG_MAXF];
        for (int f = 0; f < g.F; f++) gof[f] = go[f];
#pragma unroll
        for (int k = 0; k < 8; k++) {
            float* e = table + (size_t)c.idx[k] * g.F;
            for (int f = 0; f < g.F; f++) atomicAdd(e + f, c.w[k] * gof[f]);
        }
    }
}

// dx: one thread per point, levels in order (deterministic), the CPU's formula.
__global__ void hg_backward_x_kernel(hg_layout g, const float* params, float* dx, const float* dout, const float* x, int N) {
    for (int i = blockIdx.x * blockDim.x + threadIdx.x; i < N; i += gridDim.x * blockDim.x) {
        const float* xi = x + 3 * (size_t)i;
        float sum[3] = {0, 0, 0};
        for (int l = 0; l < g.L; l++) {
            hg_corners c;
            hg_level_corners(g, l, xi, c);
            const float* table = params + g.offset[l] * g.F;
            const float* go = dout + (size_t)i * g.D + l * g.F;
            const float s = g.scale[l];
            float ge[8];
#pragma unroll
            for (int k = 0; k < 8; k++) {
                const float* e = table + (size_t)c.idx[k] * g.F;
                float a = 0.0f;
                for (int f = 0; f < g.F; f++) a += go[f] * e[f];
                ge[k] = a;
            }
            const float t0 = c.t[0], t1 = c.t[1], t2 = c.t[2], u0 = 1 - t0, u1 = 1 - t1, u2 = 1 - t2;
            sum[0] += s * (u1 * u2 * (ge[1] - ge[0]) + t1 * u2 * (ge[3] - ge[2]) + u1 * t2 * (ge[5] - ge[4]) +
                           t1 * t2 * (ge[7] - ge[6]));
            sum[1] += s * (u0 * u2 * (ge[2] - ge[0]) + t0 * u2 * (ge[3] - ge[1]) + u0 * t2 * (ge[6] - ge[4]) +
                           t0 * t2 * (ge[7] - ge[5]));
            sum[2] += s * (u0 * u1 * (ge[4] - ge[0]) + t0 * u1 * (ge[5] - ge[1]) + u0 * t1 * (ge[6] - ge[2]) +
                           t0 * t1 * (ge[7] - ge[3]));
        }
        for (int d = 0; d < 3; d++)
            if (xi[d] >= 0 && xi[d] <= 1) dx[3 * (size_t)i + d] += sum[d];   // clamped outside
    }
}

extern "C" mlb_status mlb_cuda_hashgrid_forward(const mlb_hashgrid* g, const float* params, float* out, const float* x,
                                                int N) {
    hg_layout lay;
    MLB_TRY(make_layout(g, &lay));
    if (N < 0) return mlb_fail(MLB_ERR_ARG, "mlb_cuda_hashgrid_forward: N = %d", N);
    if (N == 0) return MLB_OK;
    hg_forward_kernel<<<mlb_grid((size_t)N * lay.L, 256), 256>>>(lay, params, out, x, N);
    MLB_CUDA_LAUNCHED("hg_forward_kernel");
    return MLB_OK;
}

extern "C" mlb_status mlb_cuda_hashgrid_backward(const mlb_hashgrid* g, const float* params, float* dparams, float* dx,
                                                 const float* dout, const float* x, int N) {
    hg_layout lay;
    MLB_TRY(make_layout(g, &lay));
    if (N < 0) return mlb_fail(MLB_ERR_ARG, "mlb_cuda_hashgrid_backward: N = %d", N);
    if (N == 0) return MLB_OK;
    if (dparams) {
        hg_backward_params_kernel<<<mlb_grid((size_t)N * lay.L, 256), 256>>>(lay, dparams, dout, x, N);
        MLB_CUDA_LAUNCHED("hg_backward_params_kernel");
    }
    if (dx) {
        hg_backward_x_kernel<<<mlb_grid(N, 128), 128>>>(lay, params, dx, dout, x, N);
        MLB_CUDA_LAUNCHED("hg_backward_x_kernel");
    }
    return MLB_OK;
}
