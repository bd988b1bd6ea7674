// The rasterizer's six ops for the stages' dual sources (core/real.h; include after it): the float
// pass calls them through the op table `be` the run hands the stage (NULL: the CPU's, for tests and
// benches), so a CUDA table can be given later; the double pass (the finite-difference references)
// calls raster.h's _f64 functions directly, as nothing but the CPU has them. `ctx` is the double
// pass's scratch: the float pass goes without it (the CPU table's ops keep a scratch of their own
// per call, the same bits). Every buffer is on be's device; tri, faces, adj are int32 (backend_ops.def).
#ifndef MATLABER_NN_RASTER_TABLE_H
#define MATLABER_NN_RASTER_TABLE_H
#include "matlaber/backend.h"
#include "matlaber/raster.h"

#define MLB_RT_BE(be) ((be) ? (be) : mlb_backend_cpu())

static inline mlb_status FN(rt_rasterize)(const mlb_backend* be, mlb_raster_ctx* ctx, int32_t* tri, real* bary,
                                         real* depth, const real* clip, int V, const int32_t* faces, int F, int H,
                                         int W) {
#ifdef MLB_F64
    (void)be;
    return mlb_rasterize_f64(ctx, tri, bary, depth, NULL, clip, V, faces, F, H, W);
#else
    (void)ctx;
    return MLB_RT_BE(be)->rasterize(tri, bary, depth, clip, V, faces, F, H, W);
#endif
}

static inline mlb_status FN(rt_rasterize_backward)(const mlb_backend* be, mlb_raster_ctx* ctx, real* dclip,
                                                  const real* dbary, const real* ddepth, const int32_t* tri,
                                                  const real* clip, int V, const int32_t* faces, int F, int H, int W) {
#ifdef MLB_F64
    (void)be;
    return mlb_rasterize_backward_f64(ctx, dclip, dbary, ddepth, tri, clip, V, faces, F, H, W);
#else
    (void)ctx;
    return MLB_RT_BE(be)->rasterize_backward(dclip, dbary, ddepth, tri, clip, V, faces, F, H, W);
#endif
}

static inline mlb_status FN(rt_interpolate)(const mlb_backend* be, real* out, const real* attr, int V, int C,
                                           const int32_t* tri, const real* bary, const int32_t* faces, int F, int H,
                                           int W) {
#ifdef MLB_F64
    (void)be;
    return mlb_interpolate_f64(out, attr, V, C, tri, bary, faces, F, H, W);
#else
    return MLB_RT_BE(be)->interpolate(out, attr, V, C, tri, bary, faces, F, H, W);
#endif
}

static inline mlb_status FN(rt_interpolate_backward)(const mlb_backend* be, mlb_raster_ctx* ctx, real* dattr,
                                                    real* dbary, const real* dout, const real* attr, int V, int C,
                                                    const int32_t* tri, const real* bary, const int32_t* faces, int F,
                                                    int H, int W) {
#ifdef MLB_F64
    (void)be;
    return mlb_interpolate_backward_f64(ctx, dattr, dbary, dout, attr, V, C, tri, bary, faces, F, H, W);
#else
    (void)ctx;
    return MLB_RT_BE(be)->interpolate_backward(dattr, dbary, dout, attr, V, C, tri, bary, faces, F, H, W);
#endif
}

static inline mlb_status FN(rt_antialias)(const mlb_backend* be, mlb_raster_ctx* ctx, real* out, real* weights,
                                         const real* color, int C, const int32_t* tri, const real* depth,
                                         const real* clip, int V, const int32_t* faces, const int32_t* adj, int F,
                                         int H, int W) {
#ifdef MLB_F64
    (void)be;
    return mlb_antialias_f64(ctx, out, weights, color, C, tri, depth, clip, V, faces, adj, F, H, W);
#else
    (void)ctx;
    return MLB_RT_BE(be)->antialias(out, weights, color, C, tri, depth, clip, V, faces, adj, F, H, W);
#endif
}

static inline mlb_status FN(rt_antialias_backward)(const mlb_backend* be, mlb_raster_ctx* ctx, real* dcolor,
                                                  real* dclip, const real* dout, const real* weights,
                                                  const real* color, int C, const int32_t* tri, const real* depth,
                                                  const real* clip, int V, const int32_t* faces, const int32_t* adj,
                                                  int F, int H, int W) {
#ifdef MLB_F64
    (void)be;
    return mlb_antialias_backward_f64(ctx, dcolor, dclip, dout, weights, color, C, tri, depth, clip, V, faces, adj, F,
                                      H, W);
#else
    (void)ctx;
    return MLB_RT_BE(be)->antialias_backward(dcolor, dclip, dout, weights, color, C, tri, depth, clip, V, faces, adj,
                                             F, H, W);
#endif
}

#undef MLB_RT_BE
#endif
