// Rasterize: per pixel the nearest triangle, its perspective-correct barycentrics and depth
// (reference.md §5), and the backward from (barycentrics, depth) to clip-space positions.
// Written over `real`, compiled as float and as double (_f64). docs/raster.md has the details.
//
// Coverage is decided on vertices snapped to 1/256 pixel with exact 64-bit integer edge functions
// and the top-left fill rule, which is the same as testing the pixel centre moved by (e, e²) for
// an infinitesimal e (right, then down): a centre exactly on a shared edge or vertex lands in
// exactly one of the triangles around it. Barycentrics and depth come from the unsnapped clip
// coordinates, so their gradients are exact.
//
// Triangles with a vertex outside the near/far planes or outside a guard band far beyond the
// image are clipped in homogeneous space (Sutherland-Hodgman); each intersection point is computed
// from the two endpoints taken in a canonical order, so two triangles that share an edge produce
// bit-identical points on it, and the clipped polygon is covered by the winding number of its
// fan, which stays exact even where snapping bends the polygon.
//
// Work: a vertex pass (snap + outcodes), a triangle pass (bounding box, depth plane), binning
// into 16×16 tiles (a triangle whose box spans more than 64 tiles goes on a list every tile
// scans), then tiles in parallel, each with its own depth buffer. Depth ties go to the lower face
// id, so the result does not depend on the order or the number of threads.
#include <math.h>
#include <omp.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/raster.h"
#include "core/real.h"
#include "render/raster_internal.h"

#define TILE 16
#define LARGE_TILES 64

enum { SLOT_VERT, SLOT_TRI, SLOT_CLIPLIST, SLOT_POLY, SLOT_COUNT, SLOT_START, SLOT_LIST, SLOT_LARGE };

typedef struct {
    const tsetup* S;
    const tpoly* polys;
    int W, H;
    real* zb;        // [TILE*TILE] depth of the tile (NULL when counting)
    int32_t* id;     // [TILE*TILE] winning face
    int32_t* count;  // [H,W] coverage counts (counting mode) or NULL
    int tx0, ty0;    // the tile's first pixel
} tile_job;

static inline void cover_pixel(tile_job* j, int t, int x, int y) {
    if (j->count) { j->count[(size_t)y * j->W + x]++; return; }
    const tsetup* s = &j->S[t];
    real d = depth_at(s, x, y);
    int k = (y - j->ty0) * TILE + (x - j->tx0);
    if (d < j->zb[k] || (d == j->zb[k] && t < j->id[k])) { j->zb[k] = d; j->id[k] = t; }
}

static void raster_in_tile(tile_job* j, int t, int x0, int x1, int y0, int y1) {
    const tsetup* s = &j->S[t];
    if (s->poly >= 0) {
        const tpoly* p = &j->polys[s->poly];
        for (int y = y0; y <= y1; y++)
            for (int x = x0; x <= x1; x++)
                if (poly_covers(p, (int64_t)x * SUB + HALF_SUB, (int64_t)y * SUB + HALF_SUB)) cover_pixel(j, t, x, y);
        return;
    }
    int64_t Px = (int64_t)x0 * SUB + HALF_SUB, Py = (int64_t)y0 * SUB + HALF_SUB;
    int64_t row[3], sx[3], sy[3];
    for (int k = 0; k < 3; k++) {
        int64_t dx = s->X[(k + 1) % 3] - s->X[k], dy = s->Y[(k + 1) % 3] - s->Y[k];
        row[k] = dx * (Py - s->Y[k]) - dy * (Px - s->X[k]) + edge_bias(dx, dy);
        sx[k] = -dy * SUB;
        sy[k] = dx * SUB;
    }
    // Per row, each edge function is linear in the pixel offset k: E + k sx >= 0 bounds k from
    // below (sx > 0) or above (sx < 0), exactly, in integers; the covered pixels are the span
    // between the bounds.
    int64_t kmax = x1 - x0;
    if (kmax < 8) {   // narrow: testing each pixel is cheaper than three divisions per row
        if (j->count) {
            for (int y = y0; y <= y1; y++) {
                int64_t e0 = row[0], e1 = row[1], e2 = row[2];
                for (int x = x0; x <= x1; x++) {
                    if ((e0 | e1 | e2) >= 0) cover_pixel(j, t, x, y);
                    e0 += sx[0]; e1 += sx[1]; e2 += sx[2];
                }
                row[0] += sy[0]; row[1] += sy[1]; row[2] += sy[2];
            }
            return;
        }
        // depth test without branches (coverage of tiny faces is a coin toss for the predictor)
        real ddx = s->dx;
        for (int y = y0; y <= y1; y++) {
            int64_t e0 = row[0], e1 = row[1], e2 = row[2];
            real* restrict zb = j->zb + (y - j->ty0) * TILE + (x0 - j->tx0);
            int32_t* restrict id = j->id + (y - j->ty0) * TILE + (x0 - j->tx0);
            real base = depth_row(s, y);
            for (int k = 0; k <= kmax; k++) {
                real d = ddx * (real)(x0 + k) + base;
                int win = ((e0 | e1 | e2) >= 0) & ((d < zb[k]) | ((d == zb[k]) & (t < id[k])));
                zb[k] = win ? d : zb[k];
                id[k] = win ? t : id[k];
                e0 += sx[0]; e1 += sx[1]; e2 += sx[2];
            }
            row[0] += sy[0]; row[1] += sy[1]; row[2] += sy[2];
        }
        return;
    }
    for (int y = y0; y <= y1; y++) {
        int64_t lo = 0, hi = kmax;
        for (int k = 0; k < 3; k++) {
            int64_t e = row[k], st = sx[k];
            if (st > 0) {
                if (e < 0) { int64_t b = (-e + st - 1) / st; if (b > lo) lo = b; }
            } else if (st < 0) {
                if (e < 0) hi = -1;
                else { int64_t b = e / -st; if (b < hi) hi = b; }
            } else if (e < 0) hi = -1;
        }
        for (int64_t k = lo; k <= hi; k++) cover_pixel(j, t, x0 + (int)k, y);
        row[0] += sy[0]; row[1] += sy[1]; row[2] += sy[2];
    }
}

static void tile_draw(tile_job* j, int t, int tx1, int ty1) {
    const tsetup* s = &j->S[t];
    int x0 = s->x0 > j->tx0 ? s->x0 : j->tx0, x1 = s->x1 < tx1 ? s->x1 : tx1;
    int y0 = s->y0 > j->ty0 ? s->y0 : j->ty0, y1 = s->y1 < ty1 ? s->y1 : ty1;
    if (x0 <= x1 && y0 <= y1) raster_in_tile(j, t, x0, x1, y0, y1);
}

// Face t into a list at its cursor (lists NULL: only counted).
static inline void bin_put(int64_t* cursor, int32_t* lists, int t) {
    if (lists) lists[*cursor] = t;
    (*cursor)++;
}

// Chunk c of nch (consecutive faces) into the lists of the tiles each face's box touches, a face
// over more than LARGE_TILES tiles into list ntiles: with lists NULL it counts them in cc[list];
// else it writes each face at its list's cursor cc[list] and advances the cursor. The two passes
// walk the faces the same way, so the fill matches the count.
static void bin_chunk(const tsetup* S, const tpoly* polys, int n_faces, int c, int nch, int ntx, int ntiles, int64_t* cc,
                      int32_t* lists) {
    int t0 = (int)((int64_t)n_faces * c / nch), t1 = (int)((int64_t)n_faces * (c + 1) / nch);
    for (int t = t0; t < t1; t++) {
        const tsetup* s = &S[t];
        if (box_empty(s) || (s->poly >= 0 && polys[s->poly].n < 3)) continue;
        int bx0 = s->x0 / TILE, bx1 = s->x1 / TILE, by0 = s->y0 / TILE, by1 = s->y1 / TILE;
        if ((bx1 - bx0 + 1) * (by1 - by0 + 1) > LARGE_TILES) { bin_put(&cc[ntiles], lists, t); continue; }
        for (int by = by0; by <= by1; by++)
            for (int bx = bx0; bx <= bx1; bx++) bin_put(&cc[by * ntx + bx], lists, t);
    }
}

// The whole rasterization; count != NULL switches to counting coverage (no depth test, no outputs).
static mlb_status rasterize_impl(mlb_raster_ctx* ctx, int32_t* tri, real* bary, real* depth, uint8_t* backfacing,
                                 int32_t* count, const real* clip, int n_verts, const int32_t* faces, int n_faces,
                                 int H, int W) {
    double G = guard_band(W, H);
    vrec* vr = mlb_rctx_get(ctx, SLOT_VERT, (size_t)n_verts * sizeof(vrec));
    tsetup* S = mlb_rctx_get(ctx, SLOT_TRI, (size_t)n_faces * sizeof(tsetup));
    if (!vr || !S) return mlb_fail(MLB_ERR_NOMEM, "mlb_rasterize: out of memory (%d faces)", n_faces);

#pragma omp parallel for schedule(static) if (n_verts > 4096)
    for (int v = 0; v < n_verts; v++) {
        setup_vertex(&vr[v], clip, v, W, H, G);
    }
    int n_clip = 0;
#pragma omp parallel for schedule(static) reduction(+ : n_clip) if (n_faces > 4096)
    for (int t = 0; t < n_faces; t++) n_clip += setup_triangle(&S[t], t, clip, faces, vr, W, H);

    tpoly* polys = NULL;
    if (n_clip) {
        int32_t* list = mlb_rctx_get(ctx, SLOT_CLIPLIST, (size_t)n_clip * sizeof(int32_t));
        polys = mlb_rctx_get(ctx, SLOT_POLY, (size_t)n_clip * sizeof(tpoly));
        if (!list || !polys) return mlb_fail(MLB_ERR_NOMEM, "mlb_rasterize: out of memory (%d clipped faces)", n_clip);
        int k = 0;
        for (int t = 0; t < n_faces; t++)
            if (S[t].poly == -2) { S[t].poly = k; list[k++] = t; }
#pragma omp parallel for schedule(dynamic, 16)
        for (int i = 0; i < n_clip; i++) setup_clipped(&S[list[i]], &polys[i], list[i], clip, faces, G, W, H);
    }

    // Binning: chunks of consecutive faces count, then fill, their tiles' lists.
    int ntx = (W + TILE - 1) / TILE, nty = (H + TILE - 1) / TILE, ntiles = ntx * nty;
    int nch = omp_get_max_threads();
    if (nch > 64) nch = 64;
    if (nch > n_faces / 1024 + 1) nch = n_faces / 1024 + 1;
    int64_t* cnt = mlb_rctx_get(ctx, SLOT_COUNT, ((size_t)nch * (ntiles + 1)) * sizeof(int64_t));
    int64_t* tstart = mlb_rctx_get(ctx, SLOT_START, ((size_t)ntiles + 2) * sizeof(int64_t));
    if (!cnt || !tstart) return mlb_fail(MLB_ERR_NOMEM, "mlb_rasterize: out of memory (%d tiles)", ntiles);
    memset(cnt, 0, (size_t)nch * (ntiles + 1) * sizeof(int64_t));
    // cnt[c * (ntiles + 1) + ntiles] counts chunk c's large faces
#pragma omp parallel for schedule(static)
    for (int c = 0; c < nch; c++) bin_chunk(S, polys, n_faces, c, nch, ntx, ntiles, cnt + (size_t)c * (ntiles + 1), NULL);
    int64_t total = 0;
    for (int b = 0; b <= ntiles; b++) {   // b = ntiles: the large list, after the tiles' lists
        tstart[b] = total;
        for (int c = 0; c < nch; c++) {
            int64_t n = cnt[(size_t)c * (ntiles + 1) + b];
            cnt[(size_t)c * (ntiles + 1) + b] = total;   // becomes chunk c's cursor in list b
            total += n;
        }
    }
    tstart[ntiles + 1] = total;
    int32_t* lists = mlb_rctx_get(ctx, SLOT_LIST, (size_t)total * sizeof(int32_t));
    if (!lists) return mlb_fail(MLB_ERR_NOMEM, "mlb_rasterize: out of memory (%lld tile entries)", (long long)total);
#pragma omp parallel for schedule(static)
    for (int c = 0; c < nch; c++) bin_chunk(S, polys, n_faces, c, nch, ntx, ntiles, cnt + (size_t)c * (ntiles + 1), lists);

#pragma omp parallel for schedule(dynamic, 1)
    for (int b = 0; b < ntiles; b++) {
        real zb[TILE * TILE];
        int32_t id[TILE * TILE];
        tile_job j = {S, polys, W, H, zb, id, count, (b % ntx) * TILE, (b / ntx) * TILE};
        int tx1 = j.tx0 + TILE - 1 < W - 1 ? j.tx0 + TILE - 1 : W - 1;
        int ty1 = j.ty0 + TILE - 1 < H - 1 ? j.ty0 + TILE - 1 : H - 1;
        for (int k = 0; k < TILE * TILE; k++) { zb[k] = (real)INFINITY; id[k] = -1; }
        if (count)
            for (int y = j.ty0; y <= ty1; y++)
                for (int x = j.tx0; x <= tx1; x++) count[(size_t)y * W + x] = 0;
        for (int64_t k = tstart[b]; k < tstart[b + 1]; k++) tile_draw(&j, lists[k], tx1, ty1);
        for (int64_t k = tstart[ntiles]; k < tstart[ntiles + 1]; k++) tile_draw(&j, lists[k], tx1, ty1);
        if (count) continue;
        // Resolve: barycentrics of the winner at each pixel centre, from clip space.
        for (int y = j.ty0; y <= ty1; y++)
            for (int x = j.tx0; x <= tx1; x++) {
                int k = (y - j.ty0) * TILE + (x - j.tx0);
                size_t p = (size_t)y * W + x;
                int t = id[k];
                tri[p] = t;
                if (t < 0) {
                    if (bary) bary[2 * p] = bary[2 * p + 1] = 0;
                    if (depth) depth[p] = 0;
                    if (backfacing) backfacing[p] = 0;
                    continue;
                }
                real sum = rast_resolve(bary ? bary + 2 * p : NULL, clip, faces, t, x, y, W, H);
                if (depth) depth[p] = zb[k];
                if (backfacing) backfacing[p] = sum < 0;
            }
    }
    return MLB_OK;
}

// rasterize_impl with ctx's scratch, or with a context of its own when ctx is NULL.
static mlb_status rasterize_in(const char* fn, mlb_raster_ctx* ctx, int32_t* tri, real* bary, real* depth, uint8_t* backfacing,
                               int32_t* count, const real* clip, int n_verts, const int32_t* faces, int n_faces, int H, int W) {
    mlb_raster_ctx* c = ctx ? ctx : mlb_raster_ctx_create();
    if (!c) return mlb_fail(MLB_ERR_NOMEM, "%s: out of memory", fn);
    mlb_status st = rasterize_impl(c, tri, bary, depth, backfacing, count, clip, n_verts, faces, n_faces, H, W);
    if (!ctx) mlb_raster_ctx_free(c);
    return st;
}

static mlb_status check_args(const char* fn, const real* clip, int n_verts, const int32_t* faces, int n_faces, int H, int W) {
    MLB_TRY(mlb_raster_check_size(fn, H, W));
    MLB_TRY(mlb_raster_check_mesh(fn, n_verts, faces, n_faces));
    if (n_verts > 0 && !clip) return mlb_fail(MLB_ERR_ARG, "%s: clip is NULL", fn);
    return MLB_OK;
}

mlb_status FN(mlb_rasterize)(mlb_raster_ctx* ctx, int32_t* tri, real* bary, real* depth, uint8_t* backfacing,
                             const real* clip, int n_verts, const int32_t* faces, int n_faces, int H, int W) {
    MLB_TRY(check_args("mlb_rasterize", clip, n_verts, faces, n_faces, H, W));
    if (!tri) return mlb_fail(MLB_ERR_ARG, "mlb_rasterize: tri (the output face ids) is NULL");
    return rasterize_in("mlb_rasterize", ctx, tri, bary, depth, backfacing, NULL, clip, n_verts, faces, n_faces, H, W);
}

mlb_status FN(mlb_raster_coverage_count)(mlb_raster_ctx* ctx, int32_t* count, const real* clip, int n_verts,
                                         const int32_t* faces, int n_faces, int H, int W) {
    MLB_TRY(check_args("mlb_raster_coverage_count", clip, n_verts, faces, n_faces, H, W));
    if (!count) return mlb_fail(MLB_ERR_ARG, "mlb_raster_coverage_count: count is NULL");
    return rasterize_in("mlb_raster_coverage_count", ctx, NULL, NULL, NULL, NULL, count, clip, n_verts, faces, n_faces, H, W);
}

mlb_status FN(mlb_rasterize_backward)(mlb_raster_ctx* ctx, real* dclip, const real* dbary, const real* ddepth,
                                      const int32_t* tri, const real* clip, int n_verts, const int32_t* faces,
                                      int n_faces, int H, int W) {
    MLB_TRY(check_args("mlb_rasterize_backward", clip, n_verts, faces, n_faces, H, W));
    if (!dclip || (!dbary && !ddepth)) return MLB_OK;
    if (!tri) return mlb_fail(MLB_ERR_ARG, "mlb_rasterize_backward: tri is NULL");
    mlb_raster_ctx* c = ctx ? ctx : mlb_raster_ctx_create();
    if (!c) return mlb_fail(MLB_ERR_NOMEM, "mlb_rasterize_backward: out of memory");
    mlb_pixel_groups g;
    mlb_status st = mlb_group_pixels(c, 0, tri, H * W, n_faces, &g);
    double* G = st == MLB_OK ? mlb_rctx_get(c, 3, (size_t)g.n_vis * 12 * sizeof(double)) : NULL;
    if (st == MLB_OK && !G) st = mlb_fail(MLB_ERR_NOMEM, "mlb_rasterize_backward: out of memory");
    if (st == MLB_OK) {
#pragma omp parallel for schedule(dynamic, 64)
        for (int k = 0; k < g.n_vis; k++) {
            int t = g.vis[k];
            real v[3][4];
            rast_load_tri(v, clip, faces, t);
            tri_moments acc;
            memset(&acc, 0, sizeof acc);
            for (int32_t q = g.start[t]; q < g.start[t + 1]; q++) pixel_moments(&acc, v, dbary, ddepth, g.pix[q], W, H);
            moments_to_grad((double(*)[4])(G + 12 * (size_t)k), &acc, v);
        }
        for (int k = 0; k < g.n_vis; k++) {
            const int32_t* f = faces + 3 * (size_t)g.vis[k];
            for (int i = 0; i < 3; i++)
                for (int cc = 0; cc < 4; cc++) dclip[4 * (size_t)f[i] + cc] += (real)G[12 * (size_t)k + 4 * i + cc];
        }
    }
    if (!ctx) mlb_raster_ctx_free(c);
    return st;
}
