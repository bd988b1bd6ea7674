// The CPU's double op table (backend_f64.h): backend.h's CPU table over the _f64 functions, for the
// double pass of the dual sources (the finite-difference references). Host memory throughout.
// This file is the double pass of nn/backend_host.h, the ops both CPU tables share: MLB_F64 comes
// before every include so that core/real.h makes `real` double and FN(name) name_f64.
#define MLB_F64 1
#include "matlaber/backend_f64.h"
#include "nn/backend_host.h"

// ---- the double table's own ops
// (element by element: the same sums on any thread count)
static mlb_status cpu_add(double* y, const double* x, size_t n) {
#pragma omp parallel for schedule(static) if (n >= 32768)
    for (size_t i = 0; i < n; i++) y[i] += x[i];
    return MLB_OK;
}
// y = shift + scale · x per column, in double (in_float: each product and sum rounded to float, the
// float table's arithmetic, then widened)
static mlb_status cpu_affine_columns(double* y, const double* x, size_t n, int C, const double* scale,
                                     const double* shift, int in_float) {
    if (C < 1 || C > 8) return mlb_fail(MLB_ERR_ARG, "affine_columns: %d columns (1..8)", C);
    for (size_t i = 0; i < n; i++)
        for (int c = 0; c < C; c++) {
            double b = shift ? shift[c] : 0, v = x[i * C + c];
            y[i * C + c] = in_float ? (double)((float)v * (float)scale[c] + (float)b) : b + scale[c] * v;
        }
    return MLB_OK;
}

// Every op of the list starts as one that fails naming itself; the ops above and backend_host.h's
// replace theirs.
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
#define F64(name) .name = cpu_##name,
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
    F64(dmtet_deform) F64(dmtet_deform_backward) F64(sdf_reg) F64(sdf_reg_backward)
    F64(marching_tets_count) F64(marching_tets_emit) F64(marching_tets_backward)
#undef F64
};
#pragma GCC diagnostic pop

const mlb_backend_f64* mlb_backend_cpu_f64(void) { return &cpu_f64_table; }
const mlb_backend_f64* mlb_backend_for_f64(mlb_device d, mlb_gemm_precision prec) {
    (void)prec;
    return d == MLB_DEVICE_CPU ? &cpu_f64_table : NULL;
}
