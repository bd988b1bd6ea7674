// The rasterizer's scratch context, the pixel grouping the backward passes share, argument checks
// and the edge topology for antialias. Compiled once (no `real` here).
#include <stdlib.h>
#include <string.h>
#include "matlaber/mt_ops.h"
#include "render/raster_internal.h"

mlb_raster_ctx* mlb_raster_ctx_create(void) { return calloc(1, sizeof(mlb_raster_ctx)); }

void mlb_raster_ctx_free(mlb_raster_ctx* ctx) {
    if (!ctx) return;
    for (int i = 0; i < MLB_RCTX_SLOTS; i++) free(ctx->buf[i]);
    free(ctx);
}

void* mlb_rctx_get(mlb_raster_ctx* ctx, int slot, size_t bytes) {
    if (bytes == 0) bytes = 1;
    if (ctx->cap[slot] >= bytes) return ctx->buf[slot];
    size_t cap = bytes + bytes / 4;   // some headroom: sizes vary a little from view to view
    free(ctx->buf[slot]);
    ctx->buf[slot] = malloc(cap);
    ctx->cap[slot] = ctx->buf[slot] ? cap : 0;
    return ctx->buf[slot];
}

mlb_status mlb_raster_check_size(const char* fn, int H, int W) {
    if (H < 1 || W < 1 || H > MLB_RASTER_MAX_SIZE || W > MLB_RASTER_MAX_SIZE)
        return mlb_fail(MLB_ERR_ARG, "%s: image size %dx%d (W x H) outside 1..%d", fn, W, H, MLB_RASTER_MAX_SIZE);
    return MLB_OK;
}

mlb_status mlb_raster_check_mesh(const char* fn, int n_verts, const int32_t* faces, int n_faces) {
    if (n_verts < 0 || n_faces < 0)
        return mlb_fail(MLB_ERR_ARG, "%s: negative mesh size (%d vertices, %d faces)", fn, n_verts, n_faces);
    if (n_faces > 0 && !faces) return mlb_fail(MLB_ERR_ARG, "%s: faces is NULL", fn);
    int64_t n = 3 * (int64_t)n_faces, bad = n;   // the first bad index, whatever the thread count
#pragma omp parallel for schedule(static) reduction(min : bad) if (n > 65536)
    for (int64_t i = 0; i < n; i++)
        if ((uint32_t)faces[i] >= (uint32_t)n_verts && i < bad) bad = i;
    if (bad < n)
        return mlb_fail(MLB_ERR_ARG, "%s: face %lld has vertex index %d, outside 0..%d", fn, (long long)(bad / 3),
                        faces[bad], n_verts - 1);
    return MLB_OK;
}

mlb_status mlb_raster_check_tri(const char* fn, const int32_t* tri, int n_pix, int n_faces) {
    int bad = n_pix;
#pragma omp parallel for schedule(static) reduction(min : bad) if (n_pix > 65536)
    for (int p = 0; p < n_pix; p++)
        if (tri[p] >= n_faces && p < bad) bad = p;
    if (bad < n_pix)
        return mlb_fail(MLB_ERR_ARG, "%s: pixel %d has triangle id %d but the mesh has %d faces", fn, bad, tri[bad], n_faces);
    return MLB_OK;
}

mlb_status mlb_group_pixels(mlb_raster_ctx* ctx, int slot0, const int32_t* tri, int n_pix, int n_faces,
                            mlb_pixel_groups* g) {
    int32_t* start = mlb_rctx_get(ctx, slot0, ((size_t)n_faces + 1) * sizeof(int32_t));
    if (!start) return mlb_fail(MLB_ERR_NOMEM, "grouping pixels by triangle: out of memory (%d faces)", n_faces);
    memset(start, 0, ((size_t)n_faces + 1) * sizeof(int32_t));
    int n_cov = 0;
    for (int p = 0; p < n_pix; p++) {
        int32_t t = tri[p];
        if (t < 0) continue;
        if (t >= n_faces)
            return mlb_fail(MLB_ERR_ARG, "pixel %d has triangle id %d but the mesh has %d faces", p, t, n_faces);
        start[t + 1]++;
        n_cov++;
    }
    int32_t* pix = mlb_rctx_get(ctx, slot0 + 1, (size_t)n_cov * sizeof(int32_t));
    int32_t* vis = mlb_rctx_get(ctx, slot0 + 2, (size_t)(n_cov < n_faces ? n_cov : n_faces) * sizeof(int32_t));
    if (!pix || !vis) return mlb_fail(MLB_ERR_NOMEM, "grouping pixels by triangle: out of memory (%d pixels)", n_cov);
    int n_vis = 0;
    for (int t = 0; t < n_faces; t++) {
        if (start[t + 1]) vis[n_vis++] = t;
        start[t + 1] += start[t];
    }
    // Fill using start[t] as the cursor of face t, then shift the cursors back into starts.
    for (int p = 0; p < n_pix; p++)
        if (tri[p] >= 0) pix[start[tri[p]]++] = p;
    for (int t = n_faces; t > 0; t--) start[t] = start[t - 1];
    start[0] = 0;
    g->start = start;
    g->pix = pix;
    g->vis = vis;
    g->n_vis = n_vis;
    return MLB_OK;
}

// The faces at each vertex (mt_ops.h mlb_vertex_faces), then per face edge the lowest other face
// in its lower end's list that holds the other end (mlb_edge_partners: the op tables' edge_topology).
mlb_status mlb_edge_topology(int32_t* adj, const int32_t* faces, int n_faces, int n_verts) {
    MLB_TRY(mlb_raster_check_mesh("mlb_edge_topology", n_verts, faces, n_faces));
    if (n_faces == 0) return MLB_OK;
    int32_t* off = malloc(((size_t)n_verts + 1) * sizeof(int32_t));
    int32_t* vf = malloc(3 * (size_t)n_faces * sizeof(int32_t));
    mlb_status s = off && vf ? mlb_vertex_faces(off, vf, faces, n_faces, n_verts)
                             : mlb_fail(MLB_ERR_NOMEM, "mlb_edge_topology: out of memory (%d faces)", n_faces);
    if (!s) mlb_edge_partners(adj, faces, n_faces, off, vf);
    free(off);
    free(vf);
    return s;
}
