// Shared between the rasterizer's files (src/render/): the scratch context, pixel grouping and,
// from render/raster_math.h, the pixel-centre / barycentric helpers. The inline helpers use `real`
// (core/real.h), so they follow the precision of the file that includes this header.
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
// The pixel-centre and barycentric helpers over `real`, shared with the GPU's kernels.
#include "render/raster_math.h"
#endif

#endif
