// The CPU's double op table (backend_f64.h): backend.h's CPU table over the _f64 functions, for the
// double pass of the dual sources (the finite-difference references). Host memory throughout.
#include "matlaber/backend_f64.h"
#include <stdlib.h>
#include <string.h>
#include "matlaber/mt_ops.h"
#include "matlaber/raster.h"
#include "matlaber/transformer_ops.h"
#include "nn/backend_host.h"

MLB_HOST_ADAPTERS(f64)

// ---- memory --------------------------------------------------------------------------------------
static mlb_status f64_alloc(double** out, size_t n) {
    *out = malloc((n ? n : 1) * sizeof(double));
    if (!*out) return mlb_fail(MLB_ERR_NOMEM, "out of memory for %.1f MB", n * 8.0 / 1e6);
    return MLB_OK;
}
static void f64_release(void* p) { free(p); }
static mlb_status f64_copy(double* dst, const double* src, size_t n) {
    if (n) memcpy(dst, src, n * sizeof(double));
    return MLB_OK;
}
static mlb_status f64_zero(double* p, size_t n) {
    if (n) memset(p, 0, n * sizeof(double));
    return MLB_OK;
}
#define f64_upload f64_copy
#define f64_download f64_copy
static mlb_status f64_copy_rows(double* dst, size_t dpitch, const double* src, size_t spitch, size_t width,
                                size_t rows) {
    for (size_t r = 0; r < rows; r++) memcpy(dst + r * dpitch, src + r * spitch, width * sizeof(double));
    return MLB_OK;
}

// ---- the networks' ops ---------------------------------------------------------------------------
static mlb_status f64_linear(const mlb_backend_f64* be, double* out, const double* in, const double* w, const double* b,
                             int B, int C, int OC) {
    linear_forward_f64(out, in, w, b, B, C, OC);
    return MLB_OK;
}
static mlb_status f64_linear_backward(const mlb_backend_f64* be, double* din, double* dw, double* db,
                                      const double* dout, const double* in, const double* w, int B, int C, int OC) {
    linear_backward_f64(din, dw, db, dout, in, w, B, C, OC);
    return MLB_OK;
}
static mlb_status f64_conv2d(const mlb_backend_f64* be, double* out, const double* in, const double* w, const double* b,
                             const mlb_conv2d* cv) {
    return conv2d_forward_f64(out, in, w, b, cv, NULL);
}
static mlb_status f64_conv2d_backward(const mlb_backend_f64* be, double* din, double* dw, double* db,
                                      const double* dout, const double* in, const double* w, const mlb_conv2d* cv) {
    return conv2d_backward_f64(din, dw, db, dout, in, w, cv, NULL);
}
static mlb_status f64_groupnorm(double* out, double* mean, double* rstd, const double* in, const double* w,
                                const double* b, int N, int C, int HW, int G, double eps, mlb_activation act) {
    return groupnorm_forward_f64(out, mean, rstd, in, w, b, N, C, HW, G, eps, act);
}
static mlb_status f64_groupnorm_backward(double* din, double* dw, double* db, const double* dout, const double* in,
                                         const double* w, const double* b, const double* mean, const double* rstd,
                                         int N, int C, int HW, int G, mlb_activation act) {
    return groupnorm_backward_f64(din, dw, db, dout, in, w, b, mean, rstd, N, C, HW, G, act);
}
static mlb_status f64_layernorm(double* out, const double* in, const double* w, const double* b, int N, int C,
                                double eps) {
    layernorm_forward_f64(out, NULL, NULL, in, w, b, N, C, eps);
    return MLB_OK;
}
static mlb_status f64_layernorm_stats(double* out, double* mean, double* rstd, const double* in, const double* w,
                                      const double* b, int N, int C, double eps) {
    layernorm_forward_f64(out, mean, rstd, in, w, b, N, C, eps);
    return MLB_OK;
}
static mlb_status f64_layernorm_backward(double* din, double* dw, double* db, const double* dout, const double* in,
                                         const double* w, const double* mean, const double* rstd, int N, int C) {
    layernorm_backward_f64(din, dw, db, dout, in, w, mean, rstd, N, C);
    return MLB_OK;
}
static mlb_status f64_activation(double* out, const double* in, size_t n, mlb_activation act) {
    activation_forward_f64(out, in, n, act);
    return MLB_OK;
}
static mlb_status f64_activation_backward(double* din, const double* dout, const double* in, size_t n,
                                          mlb_activation act) {
    activation_backward_f64(din, dout, in, n, act);
    return MLB_OK;
}
static mlb_status f64_sdpa(const mlb_backend_f64* be, double* out, double* lse, const double* q, const double* k,
                           const double* v, int B, int Tq, int Tk, int C, int NH, int ldq, int ldkv) {
    return sdpa_forward_f64(out, lse, q, k, v, B, Tq, Tk, C, NH, ldq, ldkv, NULL);
}
static mlb_status f64_sdpa_backward(const mlb_backend_f64* be, double* dq, double* dk, double* dv, const double* dout,
                                    const double* out, const double* lse, const double* q, const double* k,
                                    const double* v, int B, int Tq, int Tk, int C, int NH, int ldq, int ldkv) {
    return sdpa_backward_f64(dq, dk, dv, dout, out, lse, q, k, v, B, Tq, Tk, C, NH, ldq, ldkv, NULL);
}
static mlb_status f64_attention(double* out, const double* q, const double* k, const double* v, int ld, int B, int T,
                                int C, int NH, int causal) {
    return attention_forward_f64(out, NULL, q, k, v, ld, B, T, C, NH, causal);
}
// (element by element: the same sums on any thread count)
static mlb_status f64_add(double* y, const double* x, size_t n) {
#pragma omp parallel for schedule(static) if (n >= 32768)
    for (size_t i = 0; i < n; i++) y[i] += x[i];
    return MLB_OK;
}
static mlb_status f64_add_channel(double* x, const double* v, int N, int C, int HW) {
    for (size_t r = 0; r < (size_t)N * C; r++)
        for (int i = 0; i < HW; i++) x[r * HW + i] += v[r];
    return MLB_OK;
}
static mlb_status f64_transpose_last2(double* out, const double* in, int N, int R, int S, int accumulate) {
    transpose_last2_f64(out, in, N, R, S, accumulate);
    return MLB_OK;
}
static mlb_status f64_upsample_nearest2x(double* out, const double* in, int N, int C, int H, int W) {
    upsample_nearest2x_forward_f64(out, in, N, C, H, W);
    return MLB_OK;
}
static mlb_status f64_upsample_nearest2x_backward(double* din, const double* dout, int N, int C, int H, int W) {
    upsample_nearest2x_backward_f64(din, dout, N, C, H, W);
    return MLB_OK;
}

// ---- the shading: the light's handle is the light itself, turned per call as the CPU table turns it
static mlb_envlight f64_turned(const void* handle, double rotation) {
    mlb_envlight l = *(const mlb_envlight*)handle;
    mlb_envlight_set_rotation(&l, (float)rotation);   // a float's value: exact
    return l;
}
static mlb_status f64_shade(double* out, const double* kd, const double* ks, const double* kr, const double* n,
                            const double* v, int N, const void* handle, double rotation, mlb_fresnel fresnel) {
    mlb_envlight l = f64_turned(handle, rotation);
    return mlb_shade_forward_f64(out, kd, ks, kr, n, v, N, &l, fresnel);
}
static mlb_status f64_shade_backward(double* dkd, double* dks, double* dkr, double* dn, double* dv, const double* dout,
                                     const double* kd, const double* ks, const double* kr, const double* n,
                                     const double* v, int N, const void* handle, double rotation, mlb_fresnel fresnel) {
    mlb_envlight l = f64_turned(handle, rotation);
    return mlb_shade_backward_f64(dkd, dks, dkr, dn, dv, dout, kd, ks, kr, n, v, N, &l, fresnel);
}

// ---- the rasterizer: raster.h's _f64 functions with a scratch context of their own per call
static mlb_status f64_rasterize(int32_t* tri, double* bary, double* depth, const double* clip, int V,
                                const int32_t* faces, int F, int H, int W) {
    return mlb_rasterize_f64(NULL, tri, bary, depth, NULL, clip, V, faces, F, H, W);
}
static mlb_status f64_rasterize_backward(double* dclip, const double* dbary, const double* ddepth, const int32_t* tri,
                                         const double* clip, int V, const int32_t* faces, int F, int H, int W) {
    return mlb_rasterize_backward_f64(NULL, dclip, dbary, ddepth, tri, clip, V, faces, F, H, W);
}
static mlb_status f64_interpolate(double* out, const double* attr, int V, int C, const int32_t* tri,
                                  const double* bary, const int32_t* faces, int F, int H, int W) {
    return mlb_interpolate_f64(out, attr, V, C, tri, bary, faces, F, H, W);
}
static mlb_status f64_interpolate_backward(double* dattr, double* dbary, const double* dout, const double* attr, int V,
                                           int C, const int32_t* tri, const double* bary, const int32_t* faces, int F,
                                           int H, int W) {
    return mlb_interpolate_backward_f64(NULL, dattr, dbary, dout, attr, V, C, tri, bary, faces, F, H, W);
}
static mlb_status f64_antialias(double* out, double* weights, const double* color, int C, const int32_t* tri,
                                const double* depth, const double* clip, int V, const int32_t* faces,
                                const int32_t* adj, int F, int H, int W) {
    return mlb_antialias_f64(NULL, out, weights, color, C, tri, depth, clip, V, faces, adj, F, H, W);
}
static mlb_status f64_antialias_backward(double* dcolor, double* dclip, const double* dout, const double* weights,
                                         const double* color, int C, const int32_t* tri, const double* depth,
                                         const double* clip, int V, const int32_t* faces, const int32_t* adj, int F,
                                         int H, int W) {
    return mlb_antialias_backward_f64(NULL, dcolor, dclip, dout, weights, color, C, tri, depth, clip, V, faces, adj, F,
                                      H, W);
}
static mlb_status f64_transform_points(double* clip, const double* pos, int V, const double* m) {
    mlb_mat4 M;
    memcpy(M.m, m, sizeof M.m);
    mlb_transform_points_f64(clip, pos, V, &M);
    return MLB_OK;
}
static mlb_status f64_transform_points_backward(double* dpos, const double* dclip, int V, const double* m) {
    mlb_mat4 M;
    memcpy(M.m, m, sizeof M.m);
    mlb_transform_points_backward_f64(dpos, dclip, V, &M);
    return MLB_OK;
}
static mlb_status f64_vertex_normals(double* normal, double* sum, const double* pos, int V, const int32_t* faces,
                                     const int32_t* off, const int32_t* vf) {
    mlb_vertex_normals_f64(normal, sum, pos, V, faces, off, vf);
    return MLB_OK;
}
static mlb_status f64_vertex_normals_backward(double* dpos, const double* dnormal, const double* sum, const double* pos,
                                              int V, const int32_t* faces, const int32_t* off, const int32_t* vf) {
    mlb_vertex_normals_backward_f64(dpos, dnormal, sum, pos, V, faces, off, vf);
    return MLB_OK;
}

// ---- the appearance renderer's samples
static mlb_status f64_gather_samples(double* pts, double* nrm, double* vdir, int32_t* where, const double* pix,
                                     const int32_t* tri, const int32_t* index, int P, double ex, double ey, double ez) {
    mlb_gather_samples_f64(pts, nrm, vdir, where, pix, tri, index, P, ex, ey, ez);
    return MLB_OK;
}
static mlb_status f64_composite_srgb(double* color, const double* rgb, const int32_t* where, int m) {
    mlb_composite_srgb_f64(color, rgb, where, m);
    return MLB_OK;
}
static mlb_status f64_composite_srgb_backward(double* drgb, const double* dcolor, const double* rgb,
                                              const int32_t* where, int m) {
    mlb_composite_srgb_backward_f64(drgb, dcolor, rgb, where, m);
    return MLB_OK;
}
static mlb_status f64_downsample_box(double* out, const double* in, int H, int W, int C, int s) {
    mlb_downsample_box_f64(out, in, H, W, C, s);
    return MLB_OK;
}
static mlb_status f64_downsample_box_backward(double* din, const double* dout, int H, int W, int C, int s) {
    mlb_downsample_box_backward_f64(din, dout, H, W, C, s);
    return MLB_OK;
}
// y = shift + scale · x per column, in double (in_float: each product and sum rounded to float, the
// float table's arithmetic, then widened)
static mlb_status f64_affine_columns(double* y, const double* x, size_t n, int C, const double* scale,
                                     const double* shift, int in_float) {
    if (C < 1 || C > 8) return mlb_fail(MLB_ERR_ARG, "affine_columns: %d columns (1..8)", C);
    for (size_t i = 0; i < n; i++)
        for (int c = 0; c < C; c++) {
            double b = shift ? shift[c] : 0, v = x[i * C + c];
            y[i * C + c] = in_float ? (double)((float)v * (float)scale[c] + (float)b) : b + scale[c] * v;
        }
    return MLB_OK;
}

// Every op of the list starts as one that fails naming itself; the ops above replace theirs.
static mlb_status no_double(const char* op) {
    return mlb_fail(MLB_ERR_UNSUPPORTED, "op %s has no double implementation (the CPU's double table)", op);
}
#define float double
#define mlb_backend mlb_backend_f64
#define MLB_OP(name, cuda_fn, params) \
    static mlb_status none_##name params { return no_double(#name); }
#define MLB_GEMM_OP(name, cuda_fn, params, args) \
    static mlb_status none_##name(const mlb_backend* be, MLB_ARGS params) { return no_double(#name); }
#include "matlaber/backend_ops.def"
#undef mlb_backend
#undef float

#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Woverride-init"
static const mlb_backend_f64 cpu_f64_table = {
    .device = MLB_DEVICE_CPU, .precision = MLB_GEMM_FP32,
#define MLB_OP(name, cuda_fn, params) .name = none_##name,
#define MLB_GEMM_OP(name, cuda_fn, params, args) .name = none_##name,
#include "matlaber/backend_ops.def"
#define F64(name) .name = f64_##name,
    F64(alloc) F64(release) F64(upload) F64(download) F64(zero) F64(copy) F64(copy_rows)
    F64(linear) F64(linear_backward) F64(conv2d) F64(conv2d_backward) F64(groupnorm) F64(groupnorm_backward)
    F64(layernorm) F64(layernorm_stats) F64(layernorm_backward) F64(activation) F64(activation_backward)
    F64(sdpa) F64(sdpa_backward) F64(attention) F64(add) F64(add_channel) F64(transpose_last2)
    F64(upsample_nearest2x) F64(upsample_nearest2x_backward)
    F64(light_upload) F64(light_free) F64(shade) F64(shade_backward)
    F64(rasterize) F64(rasterize_backward) F64(interpolate) F64(interpolate_backward) F64(antialias)
    F64(antialias_backward) F64(transform_points) F64(transform_points_backward) F64(vertex_faces)
    F64(edge_topology) F64(vertex_normals) F64(vertex_normals_backward) F64(scan_i32)
    F64(covered_flags) F64(gather_samples) F64(composite_srgb) F64(composite_srgb_backward)
    F64(downsample_box) F64(downsample_box_backward) F64(affine_columns)
#undef F64
};
#pragma GCC diagnostic pop

const mlb_backend_f64* mlb_backend_cpu_f64(void) { return &cpu_f64_table; }
const mlb_backend_f64* mlb_backend_for_f64(mlb_device d, mlb_gemm_precision prec) {
    (void)prec;
    return d == MLB_DEVICE_CPU ? &cpu_f64_table : NULL;
}
