// Antialias (reference.md §5): the only source of silhouette gradients. Written over `real`,
// compiled as float and as double (_f64).
//
// Every horizontal and vertical pair of neighbouring pixels (a, b) with different face ids is
// looked at. The occluder is the nearer of the two (smaller z/w; the background is farthest;
// equal depth goes to the lower id); P is its pixel, Q the other, t its face. Along the segment
// from P's centre to Q's, each edge function a_e of a face (the homogeneous ones of the
// barycentrics) is linear, so the segment leaves t where the first of them to turn negative does:
// tau = a_e(P) / (a_e(P) - a_e(Q)). If that edge is a silhouette - a boundary edge, or one whose
// other face lies on the same side of it on screen (one face turned towards the camera, the other
// away) - the colours blend:
//   tau < 1/2: P += (1/2 - tau) (Q - P)   (the edge lies in P's footprint)
//   tau > 1/2: Q += (tau - 1/2) (P - Q)   (the occluder reaches into Q's footprint)
// with the colours of the input (blends of different pairs add). If it is not a silhouette the
// segment goes on into the face across it, and so on (up to MAX_WALK faces): on fine meshes the
// faces that turn away near an outline are thin and often cover no pixel centre, so the outline's
// silhouette edge usually belongs to a neighbour of P's face rather than to P's face itself.
// Reaching Q's face (the same surface continues) ends the walk without a blend; so does, without
// any walk, Q's face being P's neighbour across an edge that is no silhouette.
//
// The backward gives the colours their part and moves the silhouette edge's two vertices through
// tau (x, y and w of each; z plays no part). tau is clamped to [0, 1] (P's centre may lie a hair
// outside t after snapping); a clamped tau passes no gradient.
//
// Pairs are evaluated in parallel into per-pair blend weights; pixels then gather from their four
// pairs, and the position gradients of the few blended pairs are added in pixel order.
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include "matlaber/raster.h"
#include "core/real.h"
#include "render/raster_internal.h"
#include "render/antialias_math.h"

// Silhouette flags of all faces' edges for this view: bit e of sil[t] for t's edge opposite corner e.
static void silhouettes(uint8_t* sil, int8_t* fsign, const real* clip, const int32_t* faces, const int32_t* adj,
                        int n_faces) {
#pragma omp parallel for schedule(static) if (n_faces > 8192)
    for (int t = 0; t < n_faces; t++) fsign[t] = (int8_t)face_sign(t, clip, faces);
#pragma omp parallel for schedule(static) if (n_faces > 8192)
    for (int t = 0; t < n_faces; t++)
        sil[t] = (uint8_t)(is_silhouette(t, 0, clip, faces, adj, fsign) | is_silhouette(t, 1, clip, faces, adj, fsign) << 1 |
                           is_silhouette(t, 2, clip, faces, adj, fsign) << 2);
}

// Per-pair weights wgt[2p] for the pair (p, p+1) and wgt[2p+1] for (p, p+W): +alpha blends the
// first pixel towards the second, -alpha the second towards the first, 0 nothing. alpha is in
// (0, 1/2) when tau was not clamped and exactly 1/2 when it was (no position gradient).
static void aa_weights(real* wgt, uint8_t* sil, int8_t* fsign, const int32_t* tri, const real* depth, const real* clip,
                       const int32_t* faces, const int32_t* adj, int n_faces, int H, int W) {
    silhouettes(sil, fsign, clip, faces, adj, n_faces);
#pragma omp parallel for schedule(dynamic, 4)
    for (int y = 0; y < H; y++)
        for (int x = 0; x < W; x++) {
            int p = y * W + x;
            for (int dir = 0; dir < 2; dir++)
                wgt[2 * (size_t)p + dir] = aa_pair_weight(x, y, dir, tri, depth, clip, faces, adj, sil, H, W);
        }
}

// aa_weights into w, or into the context's scratch when w is NULL (*wgt: where they went), with the
// faces' signs and silhouette flags in its scratch too. *cx is ctx, or when ctx is NULL a context
// made here that the caller frees (NULL after a failure).
static mlb_status pair_weights(const char* fn, mlb_raster_ctx* ctx, mlb_raster_ctx** cx, real* w, real** wgt,
                               const int32_t* tri, const real* depth, const real* clip, const int32_t* faces,
                               const int32_t* adj, int n_faces, int H, int W) {
    *cx = ctx ? ctx : mlb_raster_ctx_create();
    if (!w && *cx) w = mlb_rctx_get(*cx, 0, 2 * (size_t)H * W * sizeof(real));
    int8_t* fsign = *cx ? mlb_rctx_get(*cx, 1, (size_t)n_faces) : NULL;
    uint8_t* sil = *cx ? mlb_rctx_get(*cx, 2, (size_t)n_faces) : NULL;
    if (!w || !fsign || !sil) {
        if (*cx && !ctx) mlb_raster_ctx_free(*cx);
        *cx = NULL;
        return mlb_fail(MLB_ERR_NOMEM, "%s: out of memory (%d pixels)", fn, H * W);
    }
    aa_weights(w, sil, fsign, tri, depth, clip, faces, adj, n_faces, H, W);
    *wgt = w;
    return MLB_OK;
}

static mlb_status check_args(const char* fn, const real* color, int C, const int32_t* tri, const real* depth,
                             const real* clip, int n_verts, const int32_t* faces, const int32_t* adj, int n_faces,
                             int H, int W) {
    MLB_TRY(mlb_raster_check_size(fn, H, W));
    if (C < 1) return mlb_fail(MLB_ERR_ARG, "%s: %d channels (need at least 1)", fn, C);
    if (!color || !tri || !depth || (n_verts > 0 && !clip) || (n_faces > 0 && !adj))
        return mlb_fail(MLB_ERR_ARG, "%s: color, tri, depth, clip or adj is NULL", fn);
    MLB_TRY(mlb_raster_check_mesh(fn, n_verts, faces, n_faces));
    int64_t n = 3 * (int64_t)n_faces, bad = n;
#pragma omp parallel for schedule(static) reduction(min : bad) if (n > 65536)
    for (int64_t i = 0; i < n; i++)
        if ((adj[i] < -1 || adj[i] >= n_faces) && i < bad) bad = i;
    if (bad < n)
        return mlb_fail(MLB_ERR_ARG, "%s: adj[%lld] = %d is not a face (stale topology?)", fn, (long long)bad, adj[bad]);
    return mlb_raster_check_tri(fn, tri, H * W, n_faces);
}

mlb_status FN(mlb_antialias)(mlb_raster_ctx* ctx, real* out, real* weights, const real* color, int C, const int32_t* tri,
                             const real* depth, const real* clip, int n_verts, const int32_t* faces, const int32_t* adj,
                             int n_faces, int H, int W) {
    MLB_TRY(check_args("mlb_antialias", color, C, tri, depth, clip, n_verts, faces, adj, n_faces, H, W));
    if (!out || out == color) return mlb_fail(MLB_ERR_ARG, "mlb_antialias: out is NULL or aliases color");
    mlb_raster_ctx* cx;
    real* wgt;
    MLB_TRY(pair_weights("mlb_antialias", ctx, &cx, weights, &wgt, tri, depth, clip, faces, adj, n_faces, H, W));
#pragma omp parallel for schedule(static)
    for (int y = 0; y < H; y++)
        for (int x = 0; x < W; x++) {
            aa_blend_pixel(out, wgt, color, C, x, y, H, W);
        }
    if (!ctx) mlb_raster_ctx_free(cx);
    return MLB_OK;
}

// One blended pair's position gradient added to dclip.
static void pair_position_grad(real* dclip, const aa_pair* r, const real* dout, const real* color, int C,
                               const real* clip, const int32_t* faces, int H, int W) {
    int j, k;
    double gj[3], gk[3];
    if (!aa_pair_position_grad(&j, &k, gj, gk, r, dout, color, C, clip, faces, H, W)) return;
    real* dj = dclip + 4 * (size_t)j;
    real* dk = dclip + 4 * (size_t)k;
    dj[0] += (real)gj[0]; dj[1] += (real)gj[1]; dj[3] += (real)gj[2];
    dk[0] += (real)gk[0]; dk[1] += (real)gk[1]; dk[3] += (real)gk[2];
}

mlb_status FN(mlb_antialias_backward)(mlb_raster_ctx* ctx, real* dcolor, real* dclip, const real* dout,
                                      const real* weights, const real* color, int C, const int32_t* tri,
                                      const real* depth, const real* clip, int n_verts, const int32_t* faces,
                                      const int32_t* adj, int n_faces, int H, int W) {
    MLB_TRY(check_args("mlb_antialias_backward", color, C, tri, depth, clip, n_verts, faces, adj, n_faces, H, W));
    if (!dcolor && !dclip) return MLB_OK;
    if (!dout) return mlb_fail(MLB_ERR_ARG, "mlb_antialias_backward: dout is NULL");
    mlb_raster_ctx* cx = NULL;
    const real* wgt = weights;
    if (!wgt) {   // recompute the forward's pair weights
        real* w;
        MLB_TRY(pair_weights("mlb_antialias_backward", ctx, &cx, NULL, &w, tri, depth, clip, faces, adj, n_faces, H, W));
        wgt = w;
    }
    if (dcolor) {
        // out[p] = color[p] (1 - sum of p's weights) + sum weight color[other]: p receives its own
        // share and the shares of the pixels that blend towards it.
#pragma omp parallel for schedule(static)
        for (int y = 0; y < H; y++)
            for (int x = 0; x < W; x++) {
                aa_dcolor_pixel(dcolor, wgt, dout, C, x, y, H, W);
            }
    }
    if (dclip) {
        // Few pairs blend (the silhouettes): add their gradients in pixel order, on one thread.
        for (int p = 0; p < H * W; p++)
            for (int dir = 0; dir < 2; dir++) {
                real w = wgt[2 * (size_t)p + dir];
                if (w == 0 || w == (real)0.5 || w == (real)-0.5) continue;   // nothing, or tau clamped
                aa_pair r;
                if (aa_eval(&r, p, dir ? p + W : p + 1, tri, depth, clip, faces, adj, NULL, H, W) && !r.clamped)
                    pair_position_grad(dclip, &r, dout, color, C, clip, faces, H, W);
            }
    }
    if (cx && !ctx) mlb_raster_ctx_free(cx);
    return MLB_OK;
}
