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

#define MAX_WALK 5   // faces visited from P's face to the silhouette, P's face included

typedef struct {
    int P, Q;    // occluder's pixel, the other pixel
    int t, e;    // the face and edge (opposite corner e) of the silhouette crossing
    real tau;    // crossing from P (0) towards Q (1), clamped to [0, 1]
    int clamped;
} aa_pair;

// det of the rows (x, y, w) of three clip-space points
static double det3(const real a[4], const real b[4], const real c[4]) {
    return (double)a[0] * ((double)b[1] * c[3] - (double)b[3] * c[1]) -
           (double)a[1] * ((double)b[0] * c[3] - (double)b[3] * c[0]) +
           (double)a[3] * ((double)b[0] * c[1] - (double)b[1] * c[0]);
}
static int sgn(double x) { return (x > 0) - (x < 0); }

// The corner of face u that is neither vertex a nor b; -1 if u does not hold the edge (a, b).
static int other_corner(const int32_t* fu, int32_t a, int32_t b) {
    int k = -1, n_ab = 0;
    for (int i = 0; i < 3; i++) {
        if (fu[i] == a || fu[i] == b) n_ab++;
        else k = i;
    }
    return n_ab == 2 ? k : -1;
}

// Where the segment P→Q leaves face t, skipping edge `skip` (the one it entered by, -1 for P's
// own face): the edge (opposite corner) whose oriented edge function is negative at Q and turns
// negative first. In a face entered on the way, an edge with P outside it too is not crossed on
// the way out (the segment grazes a corner). Returns -1 when no edge qualifies (Q is inside t)
// or t is degenerate.
static int exit_edge(const real v[3][4], real fPx, real fPy, real fQx, real fQy, int skip, real* tau) {
    real aP[3], aQ[3];
    rast_edge_a(aP, v, fPx, fPy);
    rast_edge_a(aQ, v, fQx, fQy);
    real s = aP[0] + aP[1] + aP[2];   // = det, the same anywhere; its sign orients the edge functions
    if (!(s != 0)) return -1;
    int best = -1;
    for (int k = 0; k < 3; k++) {
        if (k == skip) continue;
        real p = s > 0 ? aP[k] : -aP[k], q = s > 0 ? aQ[k] : -aQ[k];
        if (!(q < 0) || (skip >= 0 && p < 0)) continue;
        real tk = p / (p - q);
        if (best < 0 || tk < *tau) { best = k; *tau = tk; }
    }
    if (best >= 0 && !isfinite(*tau)) return -1;
    return best;
}

// The orientation of face t on screen: the sign of det(x, y, w) of its corners in their order.
static int face_sign(int t, const real* clip, const int32_t* faces) {
    const int32_t* f = faces + 3 * (size_t)t;
    return sgn(det3(clip + 4 * (size_t)f[0], clip + 4 * (size_t)f[1], clip + 4 * (size_t)f[2]));
}

// Is the edge of face t opposite its corner e a silhouette? It is when the face across has its
// third corner on t's side of the edge (the surface folds away there), or there is none.
// fsign: face_sign of every face, or NULL to compute the two needed here (the same numbers).
static int is_silhouette(int t, int e, const real* clip, const int32_t* faces, const int32_t* adj, const int8_t* fsign) {
    const int32_t* ft = faces + 3 * (size_t)t;
    int u = adj[3 * (size_t)t + e];
    int ou = u >= 0 ? other_corner(faces + 3 * (size_t)u, ft[(e + 1) % 3], ft[(e + 2) % 3]) : -1;
    if (ou < 0) return 1;
    const int32_t* fu = faces + 3 * (size_t)u;
    // side of a point = sign det(v_j, v_k, point) · sign w; (v_j, v_k, v_e) is t's own cyclic
    // order, (v_j, v_k, v_o) is u's when u lists v_j right after v_o, else the reverse
    int st = fsign ? fsign[t] : face_sign(t, clip, faces), su = fsign ? fsign[u] : face_sign(u, clip, faces);
    int parity = fu[(ou + 1) % 3] == ft[(e + 1) % 3] ? 1 : -1;
    return st * sgn(clip[4 * (size_t)ft[e] + 3]) * parity * su * sgn(clip[4 * (size_t)fu[ou] + 3]) >= 0;
}

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

// sil: the flags of silhouettes(), or NULL to decide each edge when needed (the same answers).
static int aa_eval(aa_pair* r, int pa, int pb, const int32_t* tri, const real* depth, const real* clip,
                   const int32_t* faces, const int32_t* adj, const uint8_t* sil, int H, int W) {
    int ta = tri[pa], tb = tri[pb];
    if (ta == tb) return 0;
    int P;
    if (tb < 0) P = pa;
    else if (ta < 0) P = pb;
    else P = (depth[pa] < depth[pb] || (depth[pa] == depth[pb] && ta < tb)) ? pa : pb;
    int Q = P == pa ? pb : pa, t = tri[P], tq = tri[Q], skip = -1;
#define SIL(t, e) (sil ? (sil[t] >> (e)) & 1 : is_silhouette(t, e, clip, faces, adj, NULL))
    // The common case on a fine mesh: Q's face is P's neighbour across an edge that is no
    // silhouette, the surface simply goes on.
    if (tq >= 0)
        for (int k = 0; k < 3; k++)
            if (adj[3 * (size_t)t + k] == tq && !SIL(t, k)) return 0;
    real fPx = rast_ndc_x(P % W, W), fPy = rast_ndc_y(P / W, H);
    real fQx = rast_ndc_x(Q % W, W), fQy = rast_ndc_y(Q / W, H);
    real v[3][4], tau = 0;
    for (int step = 0; step < MAX_WALK; step++) {
        rast_load_tri(v, clip, faces, t);
        int e = exit_edge(v, fPx, fPy, fQx, fQy, skip, &tau);
        if (e < 0) return 0;   // Q inside the face: something nearer covers Q there
        if (SIL(t, e)) {
            r->P = P; r->Q = Q; r->t = t; r->e = e;
            r->clamped = !(tau > 0 && tau < 1);
            r->tau = tau < 0 ? 0 : tau > 1 ? 1 : tau;
            return r->tau != (real)0.5;
        }
        int u = adj[3 * (size_t)t + e];   // not a silhouette: u exists and holds the edge
        if (u == tq || tau >= 1) return 0;   // the same surface goes on to Q
        const int32_t* ft = faces + 3 * (size_t)t;
        skip = other_corner(faces + 3 * (size_t)u, ft[(e + 1) % 3], ft[(e + 2) % 3]);
        t = u;
    }
#undef SIL
    return 0;
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
            for (int dir = 0; dir < 2; dir++) {
                real* w = wgt + 2 * (size_t)p + dir;
                *w = 0;
                if (dir ? y == H - 1 : x == W - 1) continue;
                aa_pair r;
                if (!aa_eval(&r, p, dir ? p + W : p + 1, tri, depth, clip, faces, adj, sil, H, W)) continue;
                int target = r.tau < (real)0.5 ? r.P : r.Q;
                real alpha = r.clamped ? (real)0.5 : r.tau < (real)0.5 ? (real)0.5 - r.tau : r.tau - (real)0.5;
                *w = target == p ? alpha : -alpha;
            }
        }
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
    mlb_raster_ctx* cx = ctx ? ctx : mlb_raster_ctx_create();
    real* wgt = weights ? weights : cx ? mlb_rctx_get(cx, 0, 2 * (size_t)H * W * sizeof(real)) : NULL;
    int8_t* fsign = cx ? mlb_rctx_get(cx, 1, (size_t)n_faces) : NULL;
    uint8_t* sil = cx ? mlb_rctx_get(cx, 2, (size_t)n_faces) : NULL;
    if (!wgt || !fsign || !sil) {
        if (cx && !ctx) mlb_raster_ctx_free(cx);
        return mlb_fail(MLB_ERR_NOMEM, "mlb_antialias: out of memory (%d pixels)", H * W);
    }
    aa_weights(wgt, sil, fsign, tri, depth, clip, faces, adj, n_faces, H, W);
#pragma omp parallel for schedule(static)
    for (int y = 0; y < H; y++)
        for (int x = 0; x < W; x++) {
            size_t p = (size_t)y * W + x;
            // the (up to) four pairs that blend p towards a neighbour: (weight, neighbour)
            real al[4];
            size_t ot[4];
            int n = 0;
            if (x < W - 1 && wgt[2 * p] > 0) { al[n] = wgt[2 * p]; ot[n++] = p + 1; }
            if (x > 0 && wgt[2 * (p - 1)] < 0) { al[n] = -wgt[2 * (p - 1)]; ot[n++] = p - 1; }
            if (y < H - 1 && wgt[2 * p + 1] > 0) { al[n] = wgt[2 * p + 1]; ot[n++] = p + W; }
            if (y > 0 && wgt[2 * (p - W) + 1] < 0) { al[n] = -wgt[2 * (p - W) + 1]; ot[n++] = p - W; }
            for (int c = 0; c < C; c++) {
                real cp = color[p * C + c], o = cp;
                for (int k = 0; k < n; k++) o += al[k] * (color[ot[k] * C + c] - cp);
                out[p * C + c] = o;
            }
        }
    if (!ctx) mlb_raster_ctx_free(cx);
    return MLB_OK;
}

// dtau of one blended pair → (x, y, w) of the silhouette edge's two vertices.
static void pair_position_grad(real* dclip, const aa_pair* r, const real* dout, const real* color, int C,
                               const real* clip, const int32_t* faces, int H, int W) {
    int T = r->tau < (real)0.5 ? r->P : r->Q, O = T == r->P ? r->Q : r->P;
    double dalpha = 0;
    for (int c = 0; c < C; c++)
        dalpha += (double)dout[(size_t)T * C + c] * ((double)color[(size_t)O * C + c] - color[(size_t)T * C + c]);
    double dtau = T == r->P ? -dalpha : dalpha;
    if (dtau == 0) return;
    real v[3][4], aP[3], aQ[3];
    rast_load_tri(v, clip, faces, r->t);
    real fPx = rast_ndc_x(r->P % W, W), fPy = rast_ndc_y(r->P / W, H);
    real fQx = rast_ndc_x(r->Q % W, W), fQy = rast_ndc_y(r->Q / W, H);
    rast_edge_a(aP, v, fPx, fPy);
    rast_edge_a(aQ, v, fQx, fQy);
    // tau = aP / (aP - aQ) (the sign flip of a negatively oriented face cancels in the ratio)
    double p = aP[r->e], q = aQ[r->e], den = (p - q) * (p - q);
    if (den == 0) return;
    int j = (r->e + 1) % 3, k = (r->e + 2) % 3;
    double gj[3] = {0, 0, 0}, gk[3] = {0, 0, 0};
    rast_edge_a_grad(gj, gk, v[j], v[k], fPx, fPy, dtau * (-q / den));
    rast_edge_a_grad(gj, gk, v[j], v[k], fQx, fQy, dtau * (p / den));
    real* dj = dclip + 4 * (size_t)faces[3 * (size_t)r->t + j];
    real* dk = dclip + 4 * (size_t)faces[3 * (size_t)r->t + k];
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
        cx = ctx ? ctx : mlb_raster_ctx_create();
        real* w = cx ? mlb_rctx_get(cx, 0, 2 * (size_t)H * W * sizeof(real)) : NULL;
        int8_t* fsign = cx ? mlb_rctx_get(cx, 1, (size_t)n_faces) : NULL;
        uint8_t* sil = cx ? mlb_rctx_get(cx, 2, (size_t)n_faces) : NULL;
        if (!w || !fsign || !sil) {
            if (cx && !ctx) mlb_raster_ctx_free(cx);
            return mlb_fail(MLB_ERR_NOMEM, "mlb_antialias_backward: out of memory (%d pixels)", H * W);
        }
        aa_weights(w, sil, fsign, tri, depth, clip, faces, adj, n_faces, H, W);
        wgt = w;
    }
    if (dcolor) {
        // out[p] = color[p] (1 - sum of p's weights) + sum weight color[other]: p receives its own
        // share and the shares of the pixels that blend towards it.
#pragma omp parallel for schedule(static)
        for (int y = 0; y < H; y++)
            for (int x = 0; x < W; x++) {
                size_t p = (size_t)y * W + x;
                real keep = 1, al[4], w;
                size_t from[4];
                int n = 0;
                if (x < W - 1 && (w = wgt[2 * p]) != 0) { if (w > 0) keep -= w; else { al[n] = -w; from[n++] = p + 1; } }
                if (x > 0 && (w = wgt[2 * (p - 1)]) != 0) { if (w < 0) keep += w; else { al[n] = w; from[n++] = p - 1; } }
                if (y < H - 1 && (w = wgt[2 * p + 1]) != 0) { if (w > 0) keep -= w; else { al[n] = -w; from[n++] = p + W; } }
                if (y > 0 && (w = wgt[2 * (p - W) + 1]) != 0) { if (w < 0) keep += w; else { al[n] = w; from[n++] = p - W; } }
                for (int c = 0; c < C; c++) {
                    real g = keep * dout[p * C + c];
                    for (int k = 0; k < n; k++) g += al[k] * dout[from[k] * C + c];
                    dcolor[p * C + c] += g;
                }
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
