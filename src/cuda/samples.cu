// The appearance renderer's per-sample passes on the GPU (backend_ops.def "samples"): the CPU's
// src/render/raster_samples.c and raster_composite.c over device buffers. The maths is
// render/sample_math.h's (the geometry in double on both); the sRGB curve goes through CUDA's
// powf, so composite_srgb is within a few ulp of the CPU, the rest is its bits (the roundings
// are spelled out where nvcc would otherwise fuse a multiply and an add).
#include <math.h>
#include "common.cuh"
#include "render/sample_math.h"
#include "render/area_box.h"
#include "core/philox.h"

#define GRID_STRIDE(i, n) \
    for (size_t i = (size_t)blockIdx.x * blockDim.x + threadIdx.x; i < (n); i += (size_t)gridDim.x * blockDim.x)

__global__ void covered_flags_kernel(int32_t* flags, const int32_t* tri, size_t n) {
    GRID_STRIDE(i, n) flags[i] = tri[i] >= 0;
}
extern "C" mlb_status mlb_cuda_covered_flags(int32_t* flags, const int32_t* tri, size_t n) {
    if (!n) return MLB_OK;
    covered_flags_kernel<<<mlb_grid(n, 256), 256>>>(flags, tri, n);
    MLB_CUDA_LAUNCHED("covered_flags_kernel");
    return MLB_OK;
}

__global__ void gather_samples_kernel(float* pts, float* nrm, float* vdir, int32_t* where, const float* pix,
                                      const int32_t* tri, const int32_t* index, int P, double ex, double ey, double ez) {
    GRID_STRIDE(i, (size_t)P) {
        if (tri[i] < 0) continue;
        size_t j = (size_t)index[i];
        sample_geometry(pix + 6 * i, ex, ey, ez, pts + 3 * j, nrm + 3 * j, vdir + 3 * j);
        where[j] = (int32_t)i;
    }
}
extern "C" mlb_status mlb_cuda_gather_samples(float* pts, float* nrm, float* vdir, int32_t* where, const float* pix,
                                              const int32_t* tri, const int32_t* index, int P, double ex, double ey,
                                              double ez) {
    if (P < 0) return mlb_fail(MLB_ERR_ARG, "gather_samples: %d pixels", P);
    if (!P) return MLB_OK;
    gather_samples_kernel<<<mlb_grid((size_t)P, 256), 256>>>(pts, nrm, vdir, where, pix, tri, index, P, ex, ey, ez);
    MLB_CUDA_LAUNCHED("gather_samples_kernel");
    return MLB_OK;
}

__global__ void composite_srgb_kernel(float* color, const float* rgb, const int32_t* where, int m) {
    GRID_STRIDE(j, (size_t)m) {
        float* c = color + 4 * (size_t)where[j];
        for (int ch = 0; ch < 3; ch++) c[ch] = srgb_clamped(rgb[3 * j + ch]);
        c[3] = 1;
    }
}
extern "C" mlb_status mlb_cuda_composite_srgb(float* color, const float* rgb, const int32_t* where, int m) {
    if (m < 0) return mlb_fail(MLB_ERR_ARG, "composite_srgb: %d samples", m);
    if (!m) return MLB_OK;
    composite_srgb_kernel<<<mlb_grid((size_t)m, 256), 256>>>(color, rgb, where, m);
    MLB_CUDA_LAUNCHED("composite_srgb_kernel");
    return MLB_OK;
}

__global__ void composite_srgb_backward_kernel(float* drgb, const float* dcolor, const float* rgb, const int32_t* where,
                                               int m) {
    GRID_STRIDE(j, (size_t)m) {
        for (int c = 0; c < 3; c++)
            drgb[3 * j + c] = __fadd_rn(drgb[3 * j + c],
                                        __fmul_rn(dcolor[4 * (size_t)where[j] + c], srgb_clamped_d(rgb[3 * j + c])));
    }
}
extern "C" mlb_status mlb_cuda_composite_srgb_backward(float* drgb, const float* dcolor, const float* rgb,
                                                       const int32_t* where, int m) {
    if (m < 0) return mlb_fail(MLB_ERR_ARG, "composite_srgb_backward: %d samples", m);
    if (!m || !drgb) return MLB_OK;
    composite_srgb_backward_kernel<<<mlb_grid((size_t)m, 256), 256>>>(drgb, dcolor, rgb, where, m);
    MLB_CUDA_LAUNCHED("composite_srgb_backward_kernel");
    return MLB_OK;
}

// one thread per output value: the block's samples summed in double in the CPU's order
__global__ void downsample_box_kernel(float* out, const float* in, int H, int W, int C, int s) {
    size_t Wi = (size_t)W * s;
    double inv = 1.0 / ((double)s * s);
    GRID_STRIDE(o, (size_t)H * W * C) {
        int c = (int)(o % C), x = (int)((o / C) % W), y = (int)(o / ((size_t)C * W));
        double acc = 0;
        for (int i = 0; i < s; i++) {
            const float* row = in + (((size_t)y * s + i) * Wi + (size_t)x * s) * C + c;
            for (int j = 0; j < s; j++) acc += (double)row[(size_t)j * C];
        }
        out[o] = (float)__dmul_rn(acc, inv);
    }
}
// one thread per input value: its pixel's share
__global__ void downsample_box_backward_kernel(float* din, const float* dout, int H, int W, int C, int s) {
    size_t Wi = (size_t)W * s;
    float inv = (float)(1.0 / ((double)s * s));
    GRID_STRIDE(q, (size_t)H * s * Wi * C) {
        int c = (int)(q % C);
        size_t xi = (q / C) % Wi, yi = q / ((size_t)C * Wi);
        size_t o = ((yi / s) * W + xi / s) * C + c;
        din[q] = __fadd_rn(din[q], __fmul_rn(dout[o], inv));
    }
}
static mlb_status check_box(const char* fn, int H, int W, int C, int s) {
    if (H < 0 || W < 0 || C < 1 || s < 1) return mlb_fail(MLB_ERR_ARG, "%s: %dx%d, %d channels, factor %d", fn, H, W, C, s);
    return MLB_OK;
}
extern "C" mlb_status mlb_cuda_downsample_box(float* out, const float* in, int H, int W, int C, int s) {
    MLB_TRY(check_box("downsample_box", H, W, C, s));
    size_t n = (size_t)H * W * C;
    if (!n) return MLB_OK;
    downsample_box_kernel<<<mlb_grid(n, 256), 256>>>(out, in, H, W, C, s);
    MLB_CUDA_LAUNCHED("downsample_box_kernel");
    return MLB_OK;
}
extern "C" mlb_status mlb_cuda_downsample_box_backward(float* din, const float* dout, int H, int W, int C, int s) {
    MLB_TRY(check_box("downsample_box_backward", H, W, C, s));
    size_t n = (size_t)H * s * W * s * C;
    if (!n || !din) return MLB_OK;
    downsample_box_backward_kernel<<<mlb_grid(n, 256), 256>>>(din, dout, H, W, C, s);
    MLB_CUDA_LAUNCHED("downsample_box_backward_kernel");
    return MLB_OK;
}

// ---- the guidance's conversions (image_convert.h), the CPU's bits ----
// one thread per output value: its box summed in double, rows then columns, as the CPU
__global__ void area_resize_kernel(float* dst, const float* src, int n, int H, int W, int C, int h, int w) {
    GRID_STRIDE(o, (size_t)n * C * h * w) {
        int x = (int)(o % w), y = (int)((o / w) % h), c = (int)((o / ((size_t)w * h)) % C);
        size_t b = o / ((size_t)w * h * C);
        area_box a = area_box_at(y, x, H, W, h, w);
        double acc = 0;
        for (int yy = a.y0; yy < a.y1; yy++)
            for (int xx = a.x0; xx < a.x1; xx++) acc = __dadd_rn(acc, (double)src[((b * H + yy) * W + xx) * C + c]);
        dst[o] = (float)__dmul_rn(acc, a.inv);
    }
}
// one thread per source value: the shares of the output pixels whose boxes hold it, added in the
// CPU's (row-major) order of those pixels
__global__ void area_resize_backward_kernel(float* dsrc, const float* ddst, int n, int H, int W, int C, int h, int w) {
    GRID_STRIDE(q, (size_t)n * H * W * C) {
        int c = (int)(q % C), xx = (int)((q / C) % W), yy = (int)((q / ((size_t)C * W)) % H);
        size_t b = q / ((size_t)C * W * H);
        int ya = (int)((long long)yy * h / H) - 1, yb = (int)((long long)(yy + 1) * h / H) + 1;
        int xa = (int)((long long)xx * w / W) - 1, xb = (int)((long long)(xx + 1) * w / W) + 1;
        float d = dsrc[q];
        for (int y = ya < 0 ? 0 : ya; y <= yb && y < h; y++) {
            if (yy < area_lo(y, H, h) || yy >= area_hi(y, H, h)) continue;
            for (int x = xa < 0 ? 0 : xa; x <= xb && x < w; x++) {
                area_box a = area_box_at(y, x, H, W, h, w);
                if (xx < a.x0 || xx >= a.x1) continue;
                d = __fadd_rn(d, (float)__dmul_rn((double)ddst[((b * C + c) * h + y) * w + x], a.inv));
            }
        }
        dsrc[q] = d;
    }
}
static mlb_status check_resize(const char* fn, int n, int H, int W, int C, int h, int w) {
    if (n < 0 || H < 1 || W < 1 || C < 1 || h < 1 || w < 1)
        return mlb_fail(MLB_ERR_ARG, "%s: %d images of %dx%d x %d to %dx%d", fn, n, W, H, C, w, h);
    return MLB_OK;
}
extern "C" mlb_status mlb_cuda_area_resize(float* dst, const float* src, int n, int H, int W, int C, int h, int w) {
    MLB_TRY(check_resize("area_resize", n, H, W, C, h, w));
    size_t m = (size_t)n * C * h * w;
    if (!m) return MLB_OK;
    area_resize_kernel<<<mlb_grid(m, 256), 256>>>(dst, src, n, H, W, C, h, w);
    MLB_CUDA_LAUNCHED("area_resize_kernel");
    return MLB_OK;
}
extern "C" mlb_status mlb_cuda_area_resize_backward(float* dsrc, const float* ddst, int n, int H, int W, int C, int h,
                                                    int w) {
    MLB_TRY(check_resize("area_resize_backward", n, H, W, C, h, w));
    size_t m = (size_t)n * H * W * C;
    if (!m || !dsrc) return MLB_OK;
    area_resize_backward_kernel<<<mlb_grid(m, 256), 256>>>(dsrc, ddst, n, H, W, C, h, w);
    MLB_CUDA_LAUNCHED("area_resize_backward_kernel");
    return MLB_OK;
}
// one thread per pixel
__global__ void renders_to_sd_kernel(float* x, const float* renders, int n, size_t HW, int normal) {
    GRID_STRIDE(p, (size_t)n * HW) {
        size_t b = p / HW, i = p % HW;
        const float* px = renders + p * 4;
        for (int c = 0; c < 3; c++)
            x[(b * 3 + c) * HW + i] = normal ? __fmul_rn(0.5f, __fadd_rn(px[c], px[3])) : px[c];
    }
}
__global__ void renders_to_sd_backward_kernel(float* drenders, const float* dx, int n, size_t HW, int normal) {
    GRID_STRIDE(p, (size_t)n * HW) {
        size_t b = p / HW, i = p % HW;
        float* d = drenders + p * 4;
        for (int c = 0; c < 3; c++) {
            float g = dx[(b * 3 + c) * HW + i];
            if (normal) {
                d[c] = __fadd_rn(d[c], __fmul_rn(0.5f, g));
                d[3] = __fadd_rn(d[3], __fmul_rn(0.5f, g));
            } else
                d[c] = __fadd_rn(d[c], g);
        }
    }
}
extern "C" mlb_status mlb_cuda_renders_to_sd(float* x, const float* renders, int n, int H, int W, int normal) {
    MLB_TRY(check_resize("renders_to_sd", n, H, W, 4, 1, 1));
    size_t m = (size_t)n * H * W;
    if (!m) return MLB_OK;
    renders_to_sd_kernel<<<mlb_grid(m, 256), 256>>>(x, renders, n, (size_t)H * W, normal);
    MLB_CUDA_LAUNCHED("renders_to_sd_kernel");
    return MLB_OK;
}
extern "C" mlb_status mlb_cuda_renders_to_sd_backward(float* drenders, const float* dx, int n, int H, int W, int normal) {
    MLB_TRY(check_resize("renders_to_sd_backward", n, H, W, 4, 1, 1));
    size_t m = (size_t)n * H * W;
    if (!m || !drenders) return MLB_OK;
    renders_to_sd_backward_kernel<<<mlb_grid(m, 256), 256>>>(drenders, dx, n, (size_t)H * W, normal);
    MLB_CUDA_LAUNCHED("renders_to_sd_backward_kernel");
    return MLB_OK;
}

// ---- the SDS step's latent arithmetic: the CPU's float operations, rounded one at a time ----
struct rows128 { float a[MLB_OP_MAX_ROWS], c[MLB_OP_MAX_ROWS]; };
__global__ void axpby_rows_kernel(float* out, const float* x, const float* y, size_t n, size_t total, rows128 r) {
    GRID_STRIDE(k, total) {
        size_t b = k / n;
        out[k] = __fadd_rn(__fmul_rn(r.a[b], x[k]), __fmul_rn(r.c[b], y[k]));
    }
}
extern "C" mlb_status mlb_cuda_axpby_rows(float* out, const float* x, const float* y, int B, size_t n, const float* a,
                                          const float* c) {
    if (B < 0 || B > MLB_OP_MAX_ROWS) return mlb_fail(MLB_ERR_ARG, "axpby_rows: %d rows (0..%d)", B, MLB_OP_MAX_ROWS);
    size_t total = (size_t)B * n;
    if (!total) return MLB_OK;
    rows128 r;
    for (int b = 0; b < B; b++) r.a[b] = a[b], r.c[b] = c[b];
    axpby_rows_kernel<<<mlb_grid(total, 256), 256>>>(out, x, y, n, total, r);
    MLB_CUDA_LAUNCHED("axpby_rows_kernel");
    return MLB_OK;
}
__global__ void fill_normal_kernel(float* out, size_t n, uint64_t seed, uint64_t stream, uint64_t offset) {
    GRID_STRIDE(i, n) out[i] = (float)mlb_philox_normal(seed, stream, offset + i);
}
extern "C" mlb_status mlb_cuda_fill_normal(float* out, size_t n, uint64_t seed, uint64_t stream, uint64_t offset) {
    if (!n) return MLB_OK;
    fill_normal_kernel<<<mlb_grid(n, 256), 256>>>(out, n, seed, stream, offset);
    MLB_CUDA_LAUNCHED("fill_normal_kernel");
    return MLB_OK;
}
__global__ void sds_grad_kernel(float* eps, float* grad, float* dz, const float* noise, size_t n, size_t nall, float scale,
                                rows128 r, float div, float mul) {
    GRID_STRIDE(k, nall) {
        float u = eps[nall + k];
        float e = __fadd_rn(u, __fmul_rn(scale, __fsub_rn(eps[k], u)));
        eps[k] = e;
        float g = __fmul_rn(r.a[k / n], __fsub_rn(e, noise[k]));
        if (!isfinite(g)) g = 0.0f;
        grad[k] = g;
        if (dz) dz[k] = __fmul_rn(__fdiv_rn(g, div), mul);
    }
}
// one block: each thread's share in double, then a tree
__global__ void sum_squares_kernel(float* out, const float* g, size_t n) {
    __shared__ double part[256];
    double acc = 0;
    for (size_t i = threadIdx.x; i < n; i += blockDim.x) acc = __dadd_rn(acc, __dmul_rn((double)g[i], (double)g[i]));
    part[threadIdx.x] = acc;
    __syncthreads();
    for (int s = blockDim.x / 2; s > 0; s >>= 1) {
        if ((int)threadIdx.x < s) part[threadIdx.x] = __dadd_rn(part[threadIdx.x], part[threadIdx.x + s]);
        __syncthreads();
    }
    if (threadIdx.x == 0) mlb_sumsq_split(part[0], out);
}
extern "C" mlb_status mlb_cuda_sds_grad(float* eps, float* grad, float* dz, float* sumsq, const float* noise, int B,
                                        size_t n, float scale, const float* w, float div, float mul) {
    if (B < 0 || B > MLB_OP_MAX_ROWS) return mlb_fail(MLB_ERR_ARG, "sds_grad: %d rows (0..%d)", B, MLB_OP_MAX_ROWS);
    size_t nall = (size_t)B * n;
    if (!nall) return mlb_cuda_memset(sumsq, 0, 3 * sizeof(float));
    if (!grad) return mlb_fail(MLB_ERR_UNSUPPORTED, "sds_grad on the GPU needs grad (the loss is summed from it)");
    rows128 r;
    for (int b = 0; b < B; b++) r.a[b] = w[b], r.c[b] = 0;
    sds_grad_kernel<<<mlb_grid(nall, 256), 256>>>(eps, grad, dz, noise, n, nall, scale, r, div, mul);
    MLB_CUDA_LAUNCHED("sds_grad_kernel");
    sum_squares_kernel<<<1, 256>>>(sumsq, grad, nall);
    MLB_CUDA_LAUNCHED("sum_squares_kernel");
    return MLB_OK;
}

struct affine8 { double scale[8], shift[8]; int has_shift; };
__global__ void affine_columns_kernel(float* y, const float* x, size_t n, int C, affine8 a, int in_float) {
    GRID_STRIDE(i, n * C) {
        int c = (int)(i % C);
        if (in_float) {
            float p = __fmul_rn(x[i], (float)a.scale[c]);
            y[i] = a.has_shift ? __fadd_rn(p, (float)a.shift[c]) : p;
        } else {
            double p = __dmul_rn(a.scale[c], (double)x[i]);
            y[i] = (float)(a.has_shift ? __dadd_rn(a.shift[c], p) : p);
        }
    }
}
extern "C" mlb_status mlb_cuda_affine_columns(float* y, const float* x, size_t n, int C, const double* scale,
                                              const double* shift, int in_float) {
    if (C < 1 || C > 8) return mlb_fail(MLB_ERR_ARG, "affine_columns: %d columns (1..8)", C);
    if (!n) return MLB_OK;
    affine8 a;
    a.has_shift = shift != NULL;
    for (int c = 0; c < C; c++) a.scale[c] = scale[c], a.shift[c] = shift ? shift[c] : 0;
    affine_columns_kernel<<<mlb_grid(n * C, 256), 256>>>(y, x, n, C, a, in_float);
    MLB_CUDA_LAUNCHED("affine_columns_kernel");
    return MLB_OK;
}
