// Shared between the rasterizer's files (src/render/): the scratch context, pixel grouping and
// the pixel-centre / barycentric helpers. The inline helpers use `real` (core/real.h), so they
// follow the precision of the file that includes this header.
#ifndef MATLABER_RASTER_INTERNAL_H
#define MATLABER_RASTER_INTERNAL_H
#include <stddef.h>
#include <stdint.h>
#include "matlaber/raster.h"

#define MLB_RCTX_SLOTS 12
struct mlb_raster_ctx {
    void* buf[MLB_RCTX_SLOTS];
    size_t cap[MLB_RCTX_SLOTS];
};
// Slot `slot` of ctx with room for `bytes` (contents undefined); NULL when out of memory.
void* mlb_rctx_get(mlb_raster_ctx* ctx, int slot, size_t bytes);

// Pixels grouped by the triangle that covers them (a counting sort of tri[], O(pixels + F)):
// the pixels of face f are pix[start[f] .. start[f+1]) in raster order; vis[0..n_vis) lists the
// faces with at least one pixel, ascending. Backward passes sum per face over its pixels (in
// parallel, each face by one thread) and then scatter to vertices in the order of vis, so every
// sum runs in a fixed order whatever the thread count.
typedef struct {
    const int32_t* start;   // [F + 1]
    const int32_t* pix;     // [pixels covered]
    const int32_t* vis;     // [n_vis]
    int n_vis;
} mlb_pixel_groups;
// Uses ctx slots slot0 .. slot0+2. Fails (MLB_ERR_ARG) on a tri id >= n_faces.
mlb_status mlb_group_pixels(mlb_raster_ctx* ctx, int slot0, const int32_t* tri, int n_pix, int n_faces,
                            mlb_pixel_groups* g);

// Checks shared by the entry points; `fn` names the function in the message.
mlb_status mlb_raster_check_mesh(const char* fn, int n_verts, const int32_t* faces, int n_faces);
mlb_status mlb_raster_check_size(const char* fn, int H, int W);
// Every tri[p] < n_faces (ids of -1 and below mean empty).
mlb_status mlb_raster_check_tri(const char* fn, const int32_t* tri, int n_pix, int n_faces);

#ifdef MATLABER_REAL_H
// NDC of pixel centres: x = (2 px + 1) / W - 1, y = 1 - (2 py + 1) / H.
static inline real rast_ndc_x(int px, int W) { return (real)(2 * px + 1) / (real)W - (real)1; }
static inline real rast_ndc_y(int py, int H) { return (real)1 - (real)(2 * py + 1) / (real)H; }

// The three clip-space vertices of face t as (x, y, z, w).
static inline void rast_load_tri(real v[3][4], const real* clip, const int32_t* faces, int t) {
    for (int k = 0; k < 3; k++) {
        const real* c = clip + 4 * (size_t)faces[3 * (size_t)t + k];
        v[k][0] = c[0]; v[k][1] = c[1]; v[k][2] = c[2]; v[k][3] = c[3];
    }
}
// reference.md §5: p_i' = (x_i - fx w_i, y_i - fy w_i), a0 = p1'×p2', a1 = p2'×p0', a2 = p0'×p1'.
static inline void rast_edge_a(real a[3], const real v[3][4], real fx, real fy) {
    real px[3], py[3];
    for (int k = 0; k < 3; k++) { px[k] = v[k][0] - fx * v[k][3]; py[k] = v[k][1] - fy * v[k][3]; }
    a[0] = px[1] * py[2] - py[1] * px[2];
    a[1] = px[2] * py[0] - py[2] * px[0];
    a[2] = px[0] * py[1] - py[0] * px[1];
}
// Adds d(a_e)/d(x, y, w of the two vertices j = e+1, k = e+2 of the edge) · g into gj[3], gk[3]
// (layout x, y, w) for a_e = cross(p_j', p_k') at pixel centre (fx, fy).
static inline void rast_edge_a_grad(double gj[3], double gk[3], const real vj[4], const real vk[4],
                                    double fx, double fy, double g) {
    double pjx = (double)vj[0] - fx * (double)vj[3], pjy = (double)vj[1] - fy * (double)vj[3];
    double pkx = (double)vk[0] - fx * (double)vk[3], pky = (double)vk[1] - fy * (double)vk[3];
    // a = pjx pky - pjy pkx
    double dpjx = g * pky, dpjy = -g * pkx, dpkx = -g * pjy, dpky = g * pjx;
    gj[0] += dpjx; gj[1] += dpjy; gj[2] += -fx * dpjx - fy * dpjy;
    gk[0] += dpkx; gk[1] += dpky; gk[2] += -fx * dpkx - fy * dpky;
}
#endif

#endif
