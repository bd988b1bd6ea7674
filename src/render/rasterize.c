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

#define SUB 256        // subpixel steps per pixel
#define HALF_SUB 128   // a pixel centre
#define TILE 16
#define LARGE_TILES 64
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

enum { SLOT_VERT, SLOT_TRI, SLOT_CLIPLIST, SLOT_POLY, SLOT_COUNT, SLOT_START, SLOT_LIST, SLOT_LARGE };

static int64_t floor_div(int64_t a, int64_t b) { return a >= 0 ? a / b : -((-a + b - 1) / b); }

// Fixed-point screen position of a clip-space point with w > 0 (y flipped: row 0 at the top).
static void snap(double x, double y, double w, int W, int H, int32_t* X, int32_t* Y) {
    double iw = 1.0 / w;
    *X = (int32_t)llrint((x * iw * 0.5 + 0.5) * W * SUB);
    *Y = (int32_t)llrint((0.5 - y * iw * 0.5) * H * SUB);
}

// Signed distances to the six clip planes (>= 0 inside): near, far, left, right, bottom, top.
static double plane_dist(int k, const double p[4], double G) {
    switch (k) {
    case 0: return p[2] + p[3];
    case 1: return p[3] - p[2];
    case 2: return p[0] + G * p[3];
    case 3: return G * p[3] - p[0];
    case 4: return p[1] + G * p[3];
    default: return G * p[3] - p[1];
    }
}

static uint32_t outcode(const double p[4], double G) {
    if (!isfinite(p[0]) || !isfinite(p[1]) || !isfinite(p[2]) || !isfinite(p[3])) return OC_BAD;
    uint32_t oc = 0;
    for (int k = 0; k < 6; k++)
        if (plane_dist(k, p, G) < 0) oc |= 1u << k;
    if (oc == 0 && !(p[3] > 0)) oc = OC_BAD;   // only the point (0, 0, 0, 0) is inside with w = 0
    return oc;
}

static int lex_less(const double a[4], const double b[4]) {
    for (int k = 0; k < 4; k++)
        if (a[k] != b[k]) return a[k] < b[k];
    return 0;
}

// Sutherland-Hodgman against all six planes. Returns the vertex count (0: nothing left).
static int clip_polygon(double P[POLY_MAX][4], int n, double G) {
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
static void pixel_range(int64_t lo, int64_t hi, int n, int* p0, int* p1) {
    int64_t a = -floor_div(-(lo - HALF_SUB), SUB), b = floor_div(hi - HALF_SUB, SUB);
    if (a < 0) a = 0;
    if (b > n - 1) b = n - 1;
    *p0 = (int)(a > n ? n : a);
    *p1 = (int)(b < -1 ? -1 : b);
}

static void set_box(tsetup* s, const int32_t* X, const int32_t* Y, int n, int W, int H) {
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

static int box_empty(const tsetup* s) { return s->x1 < s->x0 || s->y1 < s->y0; }

// Depth plane from clip space: a_i(f) = A_i fx + B_i fy + C_i (the cross products of the (x, y, w)
// rows), z/w = sum_i z_i a_i / det with det = sum_i w_i C_i. Returns 0 for det = 0.
static int depth_plane(tsetup* s, const double v[3][4], int W, int H) {
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
static int setup_triangle(tsetup* s, int t, const real* clip, const int32_t* faces, const vrec* vr, int W, int H) {
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

static void setup_clipped(tsetup* s, tpoly* poly, int t, const real* clip, const int32_t* faces, double G, int W, int H) {
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
static int64_t edge_bias(int64_t dx, int64_t dy) { return (dy < 0 || (dy == 0 && dx > 0)) ? 0 : -1; }

static int tri_covers(const int32_t X[3], const int32_t Y[3], int64_t Px, int64_t Py) {
    int64_t e = 0;
    for (int k = 0; k < 3; k++) {
        int64_t dx = X[(k + 1) % 3] - X[k], dy = Y[(k + 1) % 3] - Y[k];
        e |= dx * (Py - Y[k]) - dy * (Px - X[k]) + edge_bias(dx, dy);
    }
    return e >= 0;
}

// Winding number of the polygon's fan at the pixel centre (each fan triangle tested with the
// same fill rule in its own orientation): nonzero inside.
static int poly_covers(const tpoly* p, int64_t Px, int64_t Py) {
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

typedef struct {
    const tsetup* S;
    const tpoly* polys;
    int W, H;
    real* zb;        // [TILE*TILE] depth of the tile (NULL when counting)
    int32_t* id;     // [TILE*TILE] winning face
    int32_t* count;  // [H,W] coverage counts (counting mode) or NULL
    int tx0, ty0;    // the tile's first pixel
} tile_job;

// z/w at pixel (x, y); every path evaluates it in this order, so a face's depth at a pixel is one
// number whichever loop computes it.
static inline real depth_row(const tsetup* s, int y) { return s->dy * (real)y + s->d0; }
static inline real depth_at(const tsetup* s, int x, int y) { return s->dx * (real)x + depth_row(s, y); }

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

// The whole rasterization; count != NULL switches to counting coverage (no depth test, no outputs).
static mlb_status rasterize_impl(mlb_raster_ctx* ctx, int32_t* tri, real* bary, real* depth, uint8_t* backfacing,
                                 int32_t* count, const real* clip, int n_verts, const int32_t* faces, int n_faces,
                                 int H, int W) {
    double G = 262144.0 / (W > H ? W : H) - 1.0;   // guard band: |x/w|, |y/w| <= G keeps |X| < 2^25
    vrec* vr = mlb_rctx_get(ctx, SLOT_VERT, (size_t)n_verts * sizeof(vrec));
    tsetup* S = mlb_rctx_get(ctx, SLOT_TRI, (size_t)n_faces * sizeof(tsetup));
    if (!vr || !S) return mlb_fail(MLB_ERR_NOMEM, "mlb_rasterize: out of memory (%d faces)", n_faces);

#pragma omp parallel for schedule(static) if (n_verts > 4096)
    for (int v = 0; v < n_verts; v++) {
        double p[4] = {clip[4 * (size_t)v], clip[4 * (size_t)v + 1], clip[4 * (size_t)v + 2], clip[4 * (size_t)v + 3]};
        vr[v].oc = outcode(p, G);
        vr[v].X = vr[v].Y = 0;
        if (vr[v].oc == 0) snap(p[0], p[1], p[3], W, H, &vr[v].X, &vr[v].Y);
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
    for (int c = 0; c < nch; c++) {
        int64_t* cc = cnt + (size_t)c * (ntiles + 1);
        int t0 = (int)((int64_t)n_faces * c / nch), t1 = (int)((int64_t)n_faces * (c + 1) / nch);
        for (int t = t0; t < t1; t++) {
            const tsetup* s = &S[t];
            if (box_empty(s) || (s->poly >= 0 && polys[s->poly].n < 3)) continue;
            int bx0 = s->x0 / TILE, bx1 = s->x1 / TILE, by0 = s->y0 / TILE, by1 = s->y1 / TILE;
            if ((bx1 - bx0 + 1) * (by1 - by0 + 1) > LARGE_TILES) { cc[ntiles]++; continue; }
            for (int by = by0; by <= by1; by++)
                for (int bx = bx0; bx <= bx1; bx++) cc[by * ntx + bx]++;
        }
    }
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
    for (int c = 0; c < nch; c++) {
        int64_t* cc = cnt + (size_t)c * (ntiles + 1);
        int t0 = (int)((int64_t)n_faces * c / nch), t1 = (int)((int64_t)n_faces * (c + 1) / nch);
        for (int t = t0; t < t1; t++) {
            const tsetup* s = &S[t];
            if (box_empty(s) || (s->poly >= 0 && polys[s->poly].n < 3)) continue;
            int bx0 = s->x0 / TILE, bx1 = s->x1 / TILE, by0 = s->y0 / TILE, by1 = s->y1 / TILE;
            if ((bx1 - bx0 + 1) * (by1 - by0 + 1) > LARGE_TILES) { lists[cc[ntiles]++] = t; continue; }
            for (int by = by0; by <= by1; by++)
                for (int bx = bx0; bx <= bx1; bx++) lists[cc[by * ntx + bx]++] = t;
        }
    }

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
                real v[3][4], a[3];
                rast_load_tri(v, clip, faces, t);
                rast_edge_a(a, v, rast_ndc_x(x, W), rast_ndc_y(y, H));
                real sum = a[0] + a[1] + a[2];
                if (bary) {
                    real inv = sum != 0 ? (real)1 / sum : 0;
                    if (sum != 0) { bary[2 * p] = a[0] * inv; bary[2 * p + 1] = a[1] * inv; }
                    else bary[2 * p] = bary[2 * p + 1] = (real)1 / 3;
                }
                if (depth) depth[p] = zb[k];
                if (backfacing) backfacing[p] = sum < 0;
            }
    }
    return MLB_OK;
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
    mlb_raster_ctx* c = ctx ? ctx : mlb_raster_ctx_create();
    if (!c) return mlb_fail(MLB_ERR_NOMEM, "mlb_rasterize: out of memory");
    mlb_status st = rasterize_impl(c, tri, bary, depth, backfacing, NULL, clip, n_verts, faces, n_faces, H, W);
    if (!ctx) mlb_raster_ctx_free(c);
    return st;
}

mlb_status FN(mlb_raster_coverage_count)(mlb_raster_ctx* ctx, int32_t* count, const real* clip, int n_verts,
                                         const int32_t* faces, int n_faces, int H, int W) {
    MLB_TRY(check_args("mlb_raster_coverage_count", clip, n_verts, faces, n_faces, H, W));
    if (!count) return mlb_fail(MLB_ERR_ARG, "mlb_raster_coverage_count: count is NULL");
    mlb_raster_ctx* c = ctx ? ctx : mlb_raster_ctx_create();
    if (!c) return mlb_fail(MLB_ERR_NOMEM, "mlb_raster_coverage_count: out of memory");
    mlb_status st = rasterize_impl(c, NULL, NULL, NULL, NULL, count, clip, n_verts, faces, n_faces, H, W);
    if (!ctx) mlb_raster_ctx_free(c);
    return st;
}

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

static void pixel_moments(tri_moments* acc, const real v[3][4], const real* dbary, const real* ddepth, int p, int W,
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
static void moments_to_grad(double G[3][4], const tri_moments* acc, const real v[3][4]) {
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
