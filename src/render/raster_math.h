// The rasterizer's maths, written once for the CPU (src/render/rasterize.c, interpolate.c,
// antialias.c) and the GPU (src/cuda/raster.cu): pixel centres and the perspective-correct edge
// functions, the snapping, outcodes and homogeneous clipping, the triangle setup (box, depth
// plane), the exact integer coverage tests with the top-left rule, and the per-pixel terms of the
// backward to clip space. rasterize.c has the why of each (coverage, clipping, ties).
// Over `real`, which the includer defines first (core/real.h on the CPU, float in the .cu); no FMA
// contraction may be applied to it (the CPU's x86-64 build has none, raster.cu is compiled with
// -fmad=false), so both devices compute the same bits. MLB_HD: core/hd.h.
#ifndef MATLABER_RASTER_MATH_H
#define MATLABER_RASTER_MATH_H
#include <math.h>
#include <stdint.h>
#include <string.h>
#include "core/hd.h"

// clip (4) = M [p, 1] for a point p (3), in double, rounded once (M: 16 doubles, row-major, mlb_mat4's)
MLB_HD void rast_transform_point(real* clip, const real* p, const double* M) {
    double p0 = p[0], p1 = p[1], p2 = p[2];
    for (int r = 0; r < 4; r++) clip[r] = (real)(M[4 * r] * p0 + M[4 * r + 1] * p1 + M[4 * r + 2] * p2 + M[4 * r + 3]);
}
// dp (3) += dclip (4) . M's first three columns, in double, rounded once
MLB_HD void rast_transform_point_backward(real* dp, const real* d, const double* M) {
    for (int c = 0; c < 3; c++) dp[c] += (real)(d[0] * M[c] + d[1] * M[4 + c] + d[2] * M[8 + c] + d[3] * M[12 + c]);
}

// NDC of pixel centres: x = (2 px + 1) / W - 1, y = 1 - (2 py + 1) / H.
MLB_HD real rast_ndc_x(int px, int W) { return (real)(2 * px + 1) / (real)W - (real)1; }
MLB_HD real rast_ndc_y(int py, int H) { return (real)1 - (real)(2 * py + 1) / (real)H; }

// The three clip-space vertices of face t as (x, y, z, w).
MLB_HD void rast_load_tri(real v[3][4], const real* clip, const int32_t* faces, int t) {
    for (int k = 0; k < 3; k++) {
        const real* c = clip + 4 * (size_t)faces[3 * (size_t)t + k];
        v[k][0] = c[0]; v[k][1] = c[1]; v[k][2] = c[2]; v[k][3] = c[3];
    }
}
// reference.md §5: p_i' = (x_i - fx w_i, y_i - fy w_i), a0 = p1'×p2', a1 = p2'×p0', a2 = p0'×p1'.
MLB_HD void rast_edge_a(real a[3], const real v[3][4], real fx, real fy) {
    real px[3], py[3];
    for (int k = 0; k < 3; k++) { px[k] = v[k][0] - fx * v[k][3]; py[k] = v[k][1] - fy * v[k][3]; }
    a[0] = px[1] * py[2] - py[1] * px[2];
    a[1] = px[2] * py[0] - py[2] * px[0];
    a[2] = px[0] * py[1] - py[0] * px[1];
}
// Adds d(a_e)/d(x, y, w of the two vertices j = e+1, k = e+2 of the edge) · g into gj[3], gk[3]
// (layout x, y, w) for a_e = cross(p_j', p_k') at pixel centre (fx, fy).
MLB_HD void rast_edge_a_grad(double gj[3], double gk[3], const real vj[4], const real vk[4], double fx, double fy,
                             double g) {
    double pjx = (double)vj[0] - fx * (double)vj[3], pjy = (double)vj[1] - fy * (double)vj[3];
    double pkx = (double)vk[0] - fx * (double)vk[3], pky = (double)vk[1] - fy * (double)vk[3];
    // a = pjx pky - pjy pkx
    double dpjx = g * pky, dpjy = -g * pkx, dpkx = -g * pjy, dpky = g * pjx;
    gj[0] += dpjx; gj[1] += dpjy; gj[2] += -fx * dpjx - fy * dpjy;
    gk[0] += dpkx; gk[1] += dpky; gk[2] += -fx * dpkx - fy * dpky;
}

// Pixel (x, y) of face t: its barycentrics into bary2[0..1] (when not NULL; 1/3 each for a
// degenerate face) from clip space; returns the edge functions' sum, whose sign is the side seen.
MLB_HD real rast_resolve(real* bary2, const real* clip, const int32_t* faces, int t, int x, int y, int W, int H) {
    real v[3][4], a[3];
    rast_load_tri(v, clip, faces, t);
    rast_edge_a(a, v, rast_ndc_x(x, W), rast_ndc_y(y, H));
    real sum = a[0] + a[1] + a[2];
    if (bary2) {
        real inv = sum != 0 ? (real)1 / sum : 0;
        if (sum != 0) { bary2[0] = a[0] * inv; bary2[1] = a[1] * inv; }
        else bary2[0] = bary2[1] = (real)1 / 3;
    }
    return sum;
}

// ---- interpolate, per pixel ----
// o[C] = the blend of face t's three attribute rows by bary2 (0 when t < 0).
MLB_HD void rast_interpolate_pixel(real* o, const real* attr, int C, int t, const real* bary2, const int32_t* faces) {
    if (t < 0) {
        for (int c = 0; c < C; c++) o[c] = 0;
        return;
    }
    const int32_t* f = faces + 3 * (size_t)t;
    const real* a0 = attr + (size_t)f[0] * C;
    const real* a1 = attr + (size_t)f[1] * C;
    const real* a2 = attr + (size_t)f[2] * C;
    real b0 = bary2[0], b1 = bary2[1], b2 = (real)1 - b0 - b1;
    for (int c = 0; c < C; c++) o[c] = b0 * a0[c] + b1 * a1[c] + b2 * a2[c];
}
// dbary2 += (attr[i0] - attr[i2], attr[i1] - attr[i2]) . d for face t (t >= 0), summed in double.
MLB_HD void rast_interpolate_dbary(real* dbary2, const real* d, const real* attr, int C, int t, const int32_t* faces) {
    const int32_t* f = faces + 3 * (size_t)t;
    const real* a0 = attr + (size_t)f[0] * C;
    const real* a1 = attr + (size_t)f[1] * C;
    const real* a2 = attr + (size_t)f[2] * C;
    double g0 = 0, g1 = 0;
    for (int c = 0; c < C; c++) {
        g0 += (double)d[c] * (a0[c] - a2[c]);
        g1 += (double)d[c] * (a1[c] - a2[c]);
    }
    dbary2[0] += (real)g0;
    dbary2[1] += (real)g1;
}

// ---- rasterize: setup and coverage ----
#define SUB 256        // subpixel steps per pixel
#define HALF_SUB 128   // a pixel centre
#define POLY_MAX 16

enum { OC_NEAR = 1, OC_FAR = 2, OC_LEFT = 4, OC_RIGHT = 8, OC_BOTTOM = 16, OC_TOP = 32, OC_BAD = 128 };

typedef struct { int32_t X, Y; uint32_t oc; } vrec;

typedef struct {
    int32_t X[3], Y[3];        // snapped positions, ordered for a positive area (unclipped triangles)
    int16_t x0, y0, x1, y1;    // inclusive pixel box; x1 < x0 when nothing is drawn
    int32_t poly;              // -1 the triangle itself, >= 0 its clipped polygon, -2 while pending
    real dx, dy, d0;           // depth z/w at pixel (px, py) = dx px + dy py + d0
} tsetup;

typedef struct { int n; int32_t X[POLY_MAX], Y[POLY_MAX]; } tpoly;

MLB_HD int64_t floor_div(int64_t a, int64_t b) { return a >= 0 ? a / b : -((-a + b - 1) / b); }

// Fixed-point screen position of a clip-space point with w > 0 (y flipped: row 0 at the top).
MLB_HD void snap(double x, double y, double w, int W, int H, int32_t* X, int32_t* Y) {
    double iw = 1.0 / w;
    *X = (int32_t)llrint((x * iw * 0.5 + 0.5) * W * SUB);
    *Y = (int32_t)llrint((0.5 - y * iw * 0.5) * H * SUB);
}

// Signed distances to the six clip planes (>= 0 inside): near, far, left, right, bottom, top.
MLB_HD double plane_dist(int k, const double p[4], double G) {
    switch (k) {
    case 0: return p[2] + p[3];
    case 1: return p[3] - p[2];
    case 2: return p[0] + G * p[3];
    case 3: return G * p[3] - p[0];
    case 4: return p[1] + G * p[3];
    default: return G * p[3] - p[1];
    }
}

MLB_HD uint32_t outcode(const double p[4], double G) {
    if (!isfinite(p[0]) || !isfinite(p[1]) || !isfinite(p[2]) || !isfinite(p[3])) return OC_BAD;
    uint32_t oc = 0;
    for (int k = 0; k < 6; k++)
        if (plane_dist(k, p, G) < 0) oc |= 1u << k;
    if (oc == 0 && !(p[3] > 0)) oc = OC_BAD;   // only the point (0, 0, 0, 0) is inside with w = 0
    return oc;
}

// The guard band: |x/w|, |y/w| <= G keeps the snapped |X| < 2^25.
MLB_HD double guard_band(int W, int H) { return 262144.0 / (W > H ? W : H) - 1.0; }

// Vertex v's outcode and, inside every plane, its snapped position.
MLB_HD void setup_vertex(vrec* r, const real* clip, int v, int W, int H, double G) {
    double p[4] = {clip[4 * (size_t)v], clip[4 * (size_t)v + 1], clip[4 * (size_t)v + 2], clip[4 * (size_t)v + 3]};
    r->oc = outcode(p, G);
    r->X = r->Y = 0;
    if (r->oc == 0) snap(p[0], p[1], p[3], W, H, &r->X, &r->Y);
}

MLB_HD int lex_less(const double a[4], const double b[4]) {
    for (int k = 0; k < 4; k++)
        if (a[k] != b[k]) return a[k] < b[k];
    return 0;
}

// Sutherland-Hodgman against all six planes. Returns the vertex count (0: nothing left).
MLB_HD int clip_polygon(double P[POLY_MAX][4], int n, double G) {
    double Q[POLY_MAX][4];
    for (int k = 0; k < 6 && n >= 3; k++) {
        int m = 0;
        for (int i = 0; i < n; i++) {
            const double* cur = P[i];
            const double* nxt = P[(i + 1) % n];
            double dc = plane_dist(k, cur, G), dn = plane_dist(k, nxt, G);
            if (dc >= 0) {
                if (m == POLY_MAX) return 0;
                memcpy(Q[m++], cur, sizeof Q[0]);
            }
            if ((dc >= 0) != (dn >= 0)) {
                if (m == POLY_MAX) return 0;
                // The same point whichever way round the segment is walked.
                const double* a = cur; const double* b = nxt; double da = dc, db = dn;
                if (lex_less(nxt, cur)) { a = nxt; b = cur; da = dn; db = dc; }
                double t = da / (da - db);
                for (int c = 0; c < 4; c++) Q[m][c] = a[c] + t * (b[c] - a[c]);
                m++;
            }
        }
        memcpy(P, Q, (size_t)m * sizeof Q[0]);
        n = m;
    }
    return n >= 3 ? n : 0;
}

// Pixel range [p0, p1] whose centres p*SUB + HALF_SUB lie in [lo, hi], clamped to [0, n-1].
MLB_HD void pixel_range(int64_t lo, int64_t hi, int n, int* p0, int* p1) {
    int64_t a = -floor_div(-(lo - HALF_SUB), SUB), b = floor_div(hi - HALF_SUB, SUB);
    if (a < 0) a = 0;
    if (b > n - 1) b = n - 1;
    *p0 = (int)(a > n ? n : a);
    *p1 = (int)(b < -1 ? -1 : b);
}

MLB_HD void set_box(tsetup* s, const int32_t* X, const int32_t* Y, int n, int W, int H) {
    int64_t xl = X[0], xh = X[0], yl = Y[0], yh = Y[0];
    for (int i = 1; i < n; i++) {
        if (X[i] < xl) xl = X[i];
        if (X[i] > xh) xh = X[i];
        if (Y[i] < yl) yl = Y[i];
        if (Y[i] > yh) yh = Y[i];
    }
    int x0, x1, y0, y1;
    pixel_range(xl, xh, W, &x0, &x1);
    pixel_range(yl, yh, H, &y0, &y1);
    if (x1 < x0 || y1 < y0) { x0 = y0 = 1; x1 = y1 = 0; }
    s->x0 = (int16_t)x0; s->x1 = (int16_t)x1; s->y0 = (int16_t)y0; s->y1 = (int16_t)y1;
}

MLB_HD int box_empty(const tsetup* s) { return s->x1 < s->x0 || s->y1 < s->y0; }

// Depth plane from clip space: a_i(f) = A_i fx + B_i fy + C_i (the cross products of the (x, y, w)
// rows), z/w = sum_i z_i a_i / det with det = sum_i w_i C_i. Returns 0 for det = 0.
MLB_HD int depth_plane(tsetup* s, const double v[3][4], int W, int H) {
    double Az = 0, Bz = 0, Cz = 0, det = 0;
    for (int i = 0; i < 3; i++) {
        const double* a = v[(i + 1) % 3];
        const double* b = v[(i + 2) % 3];
        double A = a[1] * b[3] - a[3] * b[1], B = a[3] * b[0] - a[0] * b[3], C = a[0] * b[1] - a[1] * b[0];
        Az += v[i][2] * A; Bz += v[i][2] * B; Cz += v[i][2] * C;
        det += v[i][3] * C;
    }
    if (!(det != 0) || !isfinite(det)) return 0;
    Az /= det; Bz /= det; Cz /= det;
    // fx = px 2/W + 1/W - 1, fy = -py 2/H + 1 - 1/H
    s->dx = (real)(Az * 2.0 / W);
    s->dy = (real)(-Bz * 2.0 / H);
    s->d0 = (real)(Az * (1.0 / W - 1.0) + Bz * (1.0 - 1.0 / H) + Cz);
    return 1;
}

// Returns 1 when the triangle must be clipped (s->poly = -2, box left empty for now).
MLB_HD int setup_triangle(tsetup* s, int t, const real* clip, const int32_t* faces, const vrec* vr, int W, int H) {
    s->x0 = s->y0 = 1; s->x1 = s->y1 = 0;
    s->poly = -1;
    const int32_t* f = faces + 3 * (size_t)t;
    uint32_t o_or = vr[f[0]].oc | vr[f[1]].oc | vr[f[2]].oc, o_and = vr[f[0]].oc & vr[f[1]].oc & vr[f[2]].oc;
    if ((o_or & OC_BAD) || o_and) return 0;
    double v[3][4];
    for (int k = 0; k < 3; k++)
        for (int c = 0; c < 4; c++) v[k][c] = clip[4 * (size_t)f[k] + c];
    if (!depth_plane(s, v, W, H)) return 0;
    if (o_or) { s->poly = -2; return 1; }
    int32_t X[3] = {vr[f[0]].X, vr[f[1]].X, vr[f[2]].X}, Y[3] = {vr[f[0]].Y, vr[f[1]].Y, vr[f[2]].Y};
    int64_t area = (int64_t)(X[1] - X[0]) * (Y[2] - Y[0]) - (int64_t)(Y[1] - Y[0]) * (X[2] - X[0]);
    if (area == 0) return 0;
    if (area < 0) {
        int32_t tx = X[1], ty = Y[1];
        X[1] = X[2]; Y[1] = Y[2]; X[2] = tx; Y[2] = ty;
    }
    memcpy(s->X, X, sizeof X);
    memcpy(s->Y, Y, sizeof Y);
    set_box(s, X, Y, 3, W, H);
    return 0;
}

MLB_HD void setup_clipped(tsetup* s, tpoly* poly, int t, const real* clip, const int32_t* faces, double G, int W, int H) {
    double P[POLY_MAX][4];
    for (int k = 0; k < 3; k++)
        for (int c = 0; c < 4; c++) P[k][c] = clip[4 * (size_t)faces[3 * (size_t)t + k] + c];
    int n = clip_polygon(P, 3, G);
    poly->n = 0;
    for (int i = 0; i < n; i++) {
        if (!(P[i][3] > 0)) { poly->n = 0; break; }
        snap(P[i][0], P[i][1], P[i][3], W, H, &poly->X[i], &poly->Y[i]);
        poly->n = i + 1;
    }
    if (poly->n >= 3) set_box(s, poly->X, poly->Y, poly->n, W, H);
}

// Edge a→b at pixel centre (Px, Py) in 1/256 pixel: E = dx (Py - ay) - dy (Px - ax), positive
// inside a positively oriented triangle. On the edge (E = 0) the pixel is covered when the edge
// is a top or left one: dy < 0, or dy = 0 and dx > 0; folding that in as a -1 bias makes the
// coverage test (E0 | E1 | E2) >= 0.
MLB_HD int64_t edge_bias(int64_t dx, int64_t dy) { return (dy < 0 || (dy == 0 && dx > 0)) ? 0 : -1; }

MLB_HD int tri_covers(const int32_t X[3], const int32_t Y[3], int64_t Px, int64_t Py) {
    int64_t e = 0;
    for (int k = 0; k < 3; k++) {
        int64_t dx = X[(k + 1) % 3] - X[k], dy = Y[(k + 1) % 3] - Y[k];
        e |= dx * (Py - Y[k]) - dy * (Px - X[k]) + edge_bias(dx, dy);
    }
    return e >= 0;
}

// Winding number of the polygon's fan at the pixel centre (each fan triangle tested with the
// same fill rule in its own orientation): nonzero inside.
MLB_HD int poly_covers(const tpoly* p, int64_t Px, int64_t Py) {
    int wsum = 0;
    for (int j = 1; j + 1 < p->n; j++) {
        int32_t X[3] = {p->X[0], p->X[j], p->X[j + 1]}, Y[3] = {p->Y[0], p->Y[j], p->Y[j + 1]};
        int64_t area = (int64_t)(X[1] - X[0]) * (Y[2] - Y[0]) - (int64_t)(Y[1] - Y[0]) * (X[2] - X[0]);
        if (area == 0) continue;
        int sgn = 1;
        if (area < 0) {
            int32_t tx = X[1], ty = Y[1];
            X[1] = X[2]; Y[1] = Y[2]; X[2] = tx; Y[2] = ty;
            sgn = -1;
        }
        if (tri_covers(X, Y, Px, Py)) wsum += sgn;
    }
    return wsum != 0;
}

// z/w at pixel (x, y); every path evaluates it in this order, so a face's depth at a pixel is one
// number whichever loop computes it.
MLB_HD real depth_row(const tsetup* s, int y) { return s->dy * (real)y + s->d0; }
MLB_HD real depth_at(const tsetup* s, int x, int y) { return s->dx * (real)x + depth_row(s, y); }

// ---- backward ------------------------------------------------------------------------------------
// b_k = a_k / S (S = a0 + a1 + a2): dL/da_k = (g_k - g0 b0 - g1 b1) / S with g2 = 0.
// depth = N / D, N = sum a_i z_i, D = sum a_i w_i: dL/da_i += gd (z_i - depth w_i) / D,
// dL/dz_i = gd a_i / D, and w_i's explicit part -gd depth a_i / D.
// a_e = cross(p_j', p_k') (p' = (x - fx w, y - fy w)) has derivatives linear in (1, fx, fy):
//   d/dx_j = y_k - fy w_k    d/dy_j = fx w_k - x_k    d/dw_j = fy x_k - fx y_k
//   d/dx_k = fy w_j - y_j    d/dy_k = x_j - fx w_j    d/dw_k = fx y_j - fy x_j
// so a face sums g_e, g_e fx and g_e fy over its pixels (the moments m[e]) and turns them into
// vertex gradients once.
typedef struct { double m[3][3], dz[3], dw[3]; } tri_moments;

MLB_HD void pixel_moments(tri_moments* acc, const real v[3][4], const real* dbary, const real* ddepth, int p, int W,
                          int H) {
    int px = p % W, py = p / W;
    real fx = rast_ndc_x(px, W), fy = rast_ndc_y(py, H);
    real a[3];
    rast_edge_a(a, v, fx, fy);
    double S = (double)a[0] + a[1] + a[2];
    if (S == 0) return;
    double iS = 1 / S, da[3] = {0, 0, 0};
    if (dbary) {
        double g0 = dbary[2 * (size_t)p] * iS, g1 = dbary[2 * (size_t)p + 1] * iS;
        double c = (g0 * a[0] + g1 * a[1]) * iS;
        da[0] = g0 - c; da[1] = g1 - c; da[2] = -c;
    }
    if (ddepth && ddepth[p] != 0) {
        double gd = ddepth[p], N = 0, D = 0;
        for (int i = 0; i < 3; i++) { N += (double)a[i] * v[i][2]; D += (double)a[i] * v[i][3]; }
        if (D != 0) {
            double dep = N / D, s = gd / D;
            for (int i = 0; i < 3; i++) {
                da[i] += s * ((double)v[i][2] - dep * v[i][3]);
                acc->dz[i] += s * a[i];
                acc->dw[i] -= s * dep * a[i];
            }
        }
    }
    for (int e = 0; e < 3; e++) {
        acc->m[e][0] += da[e];
        acc->m[e][1] += da[e] * fx;
        acc->m[e][2] += da[e] * fy;
    }
}

// The moments of face v → G[3][4] (x, y, z, w of its corners).
MLB_HD void moments_to_grad(double G[3][4], const tri_moments* acc, const real v[3][4]) {
    memset(G, 0, 12 * sizeof(double));
    for (int e = 0; e < 3; e++) {
        int j = (e + 1) % 3, k = (e + 2) % 3;
        double M0 = acc->m[e][0], Mx = acc->m[e][1], My = acc->m[e][2];
        double xj = v[j][0], yj = v[j][1], wj = v[j][3], xk = v[k][0], yk = v[k][1], wk = v[k][3];
        G[j][0] += yk * M0 - wk * My; G[j][1] += wk * Mx - xk * M0; G[j][3] += xk * My - yk * Mx;
        G[k][0] += wj * My - yj * M0; G[k][1] += xj * M0 - wj * Mx; G[k][3] += yj * Mx - xj * My;
    }
    for (int i = 0; i < 3; i++) { G[i][2] += acc->dz[i]; G[i][3] += acc->dw[i]; }
}

#endif
