// Antialias's maths (the why: src/render/antialias.c), written once for the CPU (antialias.c) and
// the GPU (src/cuda/raster.cu): silhouette tests, the walk from an occluding pixel to the
// silhouette edge, the pair weights, the blend and its colour gradient per pixel, and the position
// gradient of one blended pair. Over `real`, after render/raster_math.h; no FMA contraction (as
// there), so both devices compute the same bits.
#ifndef MATLABER_ANTIALIAS_MATH_H
#define MATLABER_ANTIALIAS_MATH_H
#include "render/raster_math.h"

#define MAX_WALK 5   // faces visited from P's face to the silhouette, P's face included

typedef struct {
    int P, Q;    // occluder's pixel, the other pixel
    int t, e;    // the face and edge (opposite corner e) of the silhouette crossing
    real tau;    // crossing from P (0) towards Q (1), clamped to [0, 1]
    int clamped;
} aa_pair;

// det of the rows (x, y, w) of three clip-space points
MLB_HD double det3(const real a[4], const real b[4], const real c[4]) {
    return (double)a[0] * ((double)b[1] * c[3] - (double)b[3] * c[1]) -
           (double)a[1] * ((double)b[0] * c[3] - (double)b[3] * c[0]) +
           (double)a[3] * ((double)b[0] * c[1] - (double)b[1] * c[0]);
}
MLB_HD int sgn(double x) { return (x > 0) - (x < 0); }

// The corner of face u that is neither vertex a nor b; -1 if u does not hold the edge (a, b).
MLB_HD int other_corner(const int32_t* fu, int32_t a, int32_t b) {
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
MLB_HD int exit_edge(const real v[3][4], real fPx, real fPy, real fQx, real fQy, int skip, real* tau) {
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
MLB_HD int face_sign(int t, const real* clip, const int32_t* faces) {
    const int32_t* f = faces + 3 * (size_t)t;
    return sgn(det3(clip + 4 * (size_t)f[0], clip + 4 * (size_t)f[1], clip + 4 * (size_t)f[2]));
}

// Is the edge of face t opposite its corner e a silhouette? It is when the face across has its
// third corner on t's side of the edge (the surface folds away there), or there is none.
// fsign: face_sign of every face, or NULL to compute the two needed here (the same numbers).
MLB_HD int is_silhouette(int t, int e, const real* clip, const int32_t* faces, const int32_t* adj, const int8_t* fsign) {
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

// sil: the flags of silhouettes(), or NULL to decide each edge when needed (the same answers).
MLB_HD int aa_eval(aa_pair* r, int pa, int pb, const int32_t* tri, const real* depth, const real* clip,
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

// The weight of the pair (p, p+1) (dir 0) or (p, p+W) (dir 1) at pixel p = (x, y): +alpha blends p
// towards its neighbour, -alpha the neighbour towards p, 0 nothing (see aa_weights).
MLB_HD real aa_pair_weight(int x, int y, int dir, const int32_t* tri, const real* depth, const real* clip,
                           const int32_t* faces, const int32_t* adj, const uint8_t* sil, int H, int W) {
    int p = y * W + x;
    if (dir ? y == H - 1 : x == W - 1) return 0;
    aa_pair r;
    if (!aa_eval(&r, p, dir ? p + W : p + 1, tri, depth, clip, faces, adj, sil, H, W)) return 0;
    int target = r.tau < (real)0.5 ? r.P : r.Q;
    real alpha = r.clamped ? (real)0.5 : r.tau < (real)0.5 ? (real)0.5 - r.tau : r.tau - (real)0.5;
    return target == p ? alpha : -alpha;
}

// out at pixel (x, y): its colour blended towards the neighbours whose pairs say so.
MLB_HD void aa_blend_pixel(real* out, const real* wgt, const real* color, int C, int x, int y, int H, int W) {
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

// dcolor at pixel (x, y) += its own share of dout and the shares of the pixels blended towards it:
// out[p] = color[p] (1 - sum of p's weights) + sum weight color[other].
MLB_HD void aa_dcolor_pixel(real* dcolor, const real* wgt, const real* dout, int C, int x, int y, int H, int W) {
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

// dtau of one blended pair → the gradients gj, gk of (x, y, w) of the silhouette edge's two
// vertices *vj, *vk (overwritten); 0 when there is none.
MLB_HD int aa_pair_position_grad(int* vj, int* vk, double gj[3], double gk[3], const aa_pair* r, const real* dout,
                                 const real* color, int C, const real* clip, const int32_t* faces, int H, int W) {
    int T = r->tau < (real)0.5 ? r->P : r->Q, O = T == r->P ? r->Q : r->P;
    double dalpha = 0;
    for (int c = 0; c < C; c++)
        dalpha += (double)dout[(size_t)T * C + c] * ((double)color[(size_t)O * C + c] - color[(size_t)T * C + c]);
    double dtau = T == r->P ? -dalpha : dalpha;
    if (dtau == 0) return 0;
    real v[3][4], aP[3], aQ[3];
    rast_load_tri(v, clip, faces, r->t);
    real fPx = rast_ndc_x(r->P % W, W), fPy = rast_ndc_y(r->P / W, H);
    real fQx = rast_ndc_x(r->Q % W, W), fQy = rast_ndc_y(r->Q / W, H);
    rast_edge_a(aP, v, fPx, fPy);
    rast_edge_a(aQ, v, fQx, fQy);
    // tau = aP / (aP - aQ) (the sign flip of a negatively oriented face cancels in the ratio)
    double p = aP[r->e], q = aQ[r->e], den = (p - q) * (p - q);
    if (den == 0) return 0;
    int j = (r->e + 1) % 3, k = (r->e + 2) % 3;
    gj[0] = gj[1] = gj[2] = gk[0] = gk[1] = gk[2] = 0;
    rast_edge_a_grad(gj, gk, v[j], v[k], fPx, fPy, dtau * (-q / den));
    rast_edge_a_grad(gj, gk, v[j], v[k], fQx, fQy, dtau * (p / den));
    *vj = faces[3 * (size_t)r->t + j];
    *vk = faces[3 * (size_t)r->t + k];
    return 1;
}

#endif
