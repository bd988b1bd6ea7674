// Interpolate vertex attributes with the rasterizer's barycentrics (reference.md §5):
//   out[p, c] = b0 attr[i0, c] + b1 attr[i1, c] + (1 - b0 - b1) attr[i2, c]
// and its backward to the attributes and to the barycentrics (which mlb_rasterize_backward takes
// on to clip space). Written over `real`, compiled as float and as double (_f64).
#include <stdlib.h>
#include <string.h>
#include "matlaber/raster.h"
#include "core/real.h"
#include "render/raster_internal.h"

static mlb_status check_args(const char* fn, const real* attr, int n_verts, int C, const int32_t* tri,
                             const real* bary, const int32_t* faces, int n_faces, int H, int W) {
    MLB_TRY(mlb_raster_check_size(fn, H, W));
    if (C < 1) return mlb_fail(MLB_ERR_ARG, "%s: %d channels (need at least 1)", fn, C);
    if (n_verts < 0 || n_faces < 0 || (n_faces > 0 && !faces))
        return mlb_fail(MLB_ERR_ARG, "%s: bad mesh (%d vertices, %d faces)", fn, n_verts, n_faces);
    if (!tri || !bary || (n_verts > 0 && !attr)) return mlb_fail(MLB_ERR_ARG, "%s: tri, bary or attr is NULL", fn);
    MLB_TRY(mlb_raster_check_tri(fn, tri, H * W, n_faces));
    return mlb_raster_check_mesh(fn, n_verts, faces, n_faces);
}

mlb_status FN(mlb_interpolate)(real* out, const real* attr, int n_verts, int C, const int32_t* tri, const real* bary,
                               const int32_t* faces, int n_faces, int H, int W) {
    MLB_TRY(check_args("mlb_interpolate", attr, n_verts, C, tri, bary, faces, n_faces, H, W));
    int n_pix = H * W;
#pragma omp parallel for schedule(static) if (n_pix > 4096)
    for (int p = 0; p < n_pix; p++) {
        rast_interpolate_pixel(out + (size_t)p * C, attr, C, tri[p], bary + 2 * (size_t)p, faces);
    }
    return MLB_OK;
}

mlb_status FN(mlb_interpolate_backward)(mlb_raster_ctx* ctx, real* dattr, real* dbary, const real* dout,
                                        const real* attr, int n_verts, int C, const int32_t* tri, const real* bary,
                                        const int32_t* faces, int n_faces, int H, int W) {
    MLB_TRY(check_args("mlb_interpolate_backward", attr, n_verts, C, tri, bary, faces, n_faces, H, W));
    int n_pix = H * W;
    if (dbary) {   // per pixel, no sharing
#pragma omp parallel for schedule(static) if (n_pix > 4096)
        for (int p = 0; p < n_pix; p++) {
            int t = tri[p];
            if (t < 0) continue;
            rast_interpolate_dbary(dbary + 2 * (size_t)p, dout + (size_t)p * C, attr, C, t, faces);
        }
    }
    if (!dattr) return MLB_OK;
    // Attributes are shared between pixels: sum per face over its pixels, then per vertex in the
    // order of the visible faces (raster_internal.h: mlb_group_pixels).
    mlb_raster_ctx* cx = ctx ? ctx : mlb_raster_ctx_create();
    if (!cx) return mlb_fail(MLB_ERR_NOMEM, "mlb_interpolate_backward: out of memory");
    mlb_pixel_groups g;
    mlb_status st = mlb_group_pixels(cx, 0, tri, n_pix, n_faces, &g);
    double* G = st == MLB_OK ? mlb_rctx_get(cx, 3, (size_t)g.n_vis * 3 * C * sizeof(double)) : NULL;
    if (st == MLB_OK && !G) st = mlb_fail(MLB_ERR_NOMEM, "mlb_interpolate_backward: out of memory (%d faces x %d channels)", g.n_vis, C);
    if (st == MLB_OK) {
#pragma omp parallel for schedule(dynamic, 64)
        for (int k = 0; k < g.n_vis; k++) {
            int t = g.vis[k];
            double* acc = G + (size_t)k * 3 * C;
            memset(acc, 0, 3 * (size_t)C * sizeof(double));
            for (int32_t q = g.start[t]; q < g.start[t + 1]; q++) {
                int p = g.pix[q];
                const real* d = dout + (size_t)p * C;
                double b0 = bary[2 * (size_t)p], b1 = bary[2 * (size_t)p + 1], b2 = 1.0 - b0 - b1;
                for (int c = 0; c < C; c++) {
                    acc[c] += b0 * d[c];
                    acc[C + c] += b1 * d[c];
                    acc[2 * C + c] += b2 * d[c];
                }
            }
        }
        for (int k = 0; k < g.n_vis; k++) {
            const int32_t* f = faces + 3 * (size_t)g.vis[k];
            const double* acc = G + (size_t)k * 3 * C;
            for (int i = 0; i < 3; i++)
                for (int c = 0; c < C; c++) dattr[(size_t)f[i] * C + c] += (real)acc[i * C + c];
        }
    }
    if (!ctx) mlb_raster_ctx_free(cx);
    return st;
}
