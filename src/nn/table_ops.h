// Memory and the renderer's per-pixel ops for the stages' dual sources (core/real.h; include after
// it and nn/raster_table.h): the float pass allocates through the stage's op table and runs the
// table's ops, so its buffers live on that table's device; the double pass (finite-difference
// references) holds host memory and calls raster_api.inc's _f64 functions. int32 buffers are
// allocated as that many reals. Used by the appearance renderer and the geometry fit.
#ifndef MATLABER_TABLE_OPS_H
#define MATLABER_TABLE_OPS_H
#include <stdlib.h>
#include <string.h>
#include "matlaber/backend.h"
#include "matlaber/mt_ops.h"
#include "matlaber/raster.h"

typedef struct { real* p; size_t cap; } FN(tbuf);   // cap in reals

static void FN(tbuf_free)(const mlb_backend* be, FN(tbuf)* b) {
#ifdef MLB_F64
    (void)be;
    free(b->p);
#else
    if (b->p) be->release(b->p);
#endif
    b->p = NULL;
    b->cap = 0;
}
// At least n reals (grown, never shrunk); NULL out of memory
static real* FN(tbuf_get)(const mlb_backend* be, FN(tbuf)* b, size_t n) {
    if (n < 1) n = 1;
    if (b->p && n <= b->cap) return b->p;
    FN(tbuf_free)(be, b);
#ifdef MLB_F64
    b->p = malloc(sizeof(real) * n);
#else
    if (be->alloc(&b->p, n) != MLB_OK) b->p = NULL;
#endif
    b->cap = b->p ? n : 0;
    return b->p;
}

#ifdef MLB_F64
#define T_OK(expr) ((expr), MLB_OK)
static inline mlb_status t_upload_f64(const mlb_backend* be, double* dst, const double* src, size_t n) {
    (void)be;
    memcpy(dst, src, sizeof(double) * n);
    return MLB_OK;
}
#define t_download_f64 t_upload_f64
static inline mlb_status t_upload_i32_f64(const mlb_backend* be, int32_t* dst, const int32_t* src, size_t n) {
    (void)be;
    memcpy(dst, src, sizeof(int32_t) * n);
    return MLB_OK;
}
static inline mlb_status t_zero_f64(const mlb_backend* be, double* p, size_t n) {
    (void)be;
    memset(p, 0, sizeof(double) * n);
    return MLB_OK;
}
static inline mlb_status t_copy_rows_f64(const mlb_backend* be, double* dst, size_t dpitch, const double* src,
                                         size_t spitch, size_t width, size_t rows) {
    (void)be;
    for (size_t r = 0; r < rows; r++) memcpy(dst + r * dpitch, src + r * spitch, width * sizeof(double));
    return MLB_OK;
}
#define T_COVERED(be, flags, tri, n) T_OK(mlb_covered_flags(flags, tri, (long)(n)))
#define T_SCAN(be, out, in, n) T_OK(mlb_scan_i32(out, in, n))
#define T_GATHER(be, ...) T_OK(mlb_gather_samples_f64(__VA_ARGS__))
#define T_COMPOSITE(be, ...) T_OK(mlb_composite_srgb_f64(__VA_ARGS__))
#define T_COMPOSITE_BACKWARD(be, ...) T_OK(mlb_composite_srgb_backward_f64(__VA_ARGS__))
#define T_DOWNSAMPLE(be, ...) T_OK(mlb_downsample_box_f64(__VA_ARGS__))
#define T_DOWNSAMPLE_BACKWARD(be, ...) T_OK(mlb_downsample_box_backward_f64(__VA_ARGS__))
#define T_TRANSFORM(be, clip, pos, V, mat) T_OK(mlb_transform_points_f64(clip, pos, V, mat))
#define T_TRANSFORM_BACKWARD(be, dpos, dclip, V, mat) T_OK(mlb_transform_points_backward_f64(dpos, dclip, V, mat))
#define T_VERTEX_FACES(be, ...) mlb_vertex_faces(__VA_ARGS__)
#define T_EDGE_TOPOLOGY(be, ...) T_OK(mlb_edge_partners(__VA_ARGS__))
#define T_VERTEX_NORMALS(be, ...) T_OK(mlb_vertex_normals_f64(__VA_ARGS__))
#define T_VERTEX_NORMALS_BACKWARD(be, ...) T_OK(mlb_vertex_normals_backward_f64(__VA_ARGS__))
static inline mlb_status t_add_f64(const mlb_backend* be, double* y, const double* x, size_t n) {
    (void)be;
    for (size_t i = 0; i < n; i++) y[i] += x[i];
    return MLB_OK;
}
static inline mlb_status t_ones_f64(const mlb_backend* be, double* p, size_t n) {
    (void)be;
    for (size_t i = 0; i < n; i++) p[i] = 1;
    return MLB_OK;
}
#else
static inline mlb_status t_upload(const mlb_backend* be, float* dst, const float* src, size_t n) {
    return be->upload(dst, src, n);
}
static inline mlb_status t_upload_i32(const mlb_backend* be, int32_t* dst, const int32_t* src, size_t n) {
    return be->upload((float*)dst, (const float*)src, n);   // int32 bits travel as floats
}
static inline mlb_status t_download(const mlb_backend* be, float* dst, const float* src, size_t n) {
    return be->download(dst, src, n);
}
static inline mlb_status t_zero(const mlb_backend* be, float* p, size_t n) { return be->zero(p, n); }
static inline mlb_status t_copy_rows(const mlb_backend* be, float* dst, size_t dpitch, const float* src, size_t spitch,
                                     size_t width, size_t rows) {
    return be->copy_rows(dst, dpitch, src, spitch, width, rows);
}
#define T_COVERED(be, flags, tri, n) (be)->covered_flags(flags, tri, n)
#define T_SCAN(be, out, in, n) (be)->scan_i32(out, in, n)
#define T_GATHER(be, ...) (be)->gather_samples(__VA_ARGS__)
#define T_COMPOSITE(be, ...) (be)->composite_srgb(__VA_ARGS__)
#define T_COMPOSITE_BACKWARD(be, ...) (be)->composite_srgb_backward(__VA_ARGS__)
#define T_DOWNSAMPLE(be, ...) (be)->downsample_box(__VA_ARGS__)
#define T_DOWNSAMPLE_BACKWARD(be, ...) (be)->downsample_box_backward(__VA_ARGS__)
#define T_TRANSFORM(be, clip, pos, V, mat) (be)->transform_points(clip, pos, V, (mat)->m)
#define T_TRANSFORM_BACKWARD(be, dpos, dclip, V, mat) (be)->transform_points_backward(dpos, dclip, V, (mat)->m)
#define T_VERTEX_FACES(be, ...) (be)->vertex_faces(__VA_ARGS__)
#define T_EDGE_TOPOLOGY(be, ...) (be)->edge_topology(__VA_ARGS__)
#define T_VERTEX_NORMALS(be, ...) (be)->vertex_normals(__VA_ARGS__)
#define T_VERTEX_NORMALS_BACKWARD(be, ...) (be)->vertex_normals_backward(__VA_ARGS__)
static inline mlb_status t_add(const mlb_backend* be, float* y, const float* x, size_t n) { return be->add(y, x, n); }
// p [n] = 1: zeros mapped by 0 x + 1 (no upload)
static inline mlb_status t_ones(const mlb_backend* be, float* p, size_t n) {
    static const double zero = 0, one = 1;
    mlb_status s = be->zero(p, n);
    return s ? s : be->affine_columns(p, p, n, 1, &zero, &one, 0);
}
#endif
#endif
