// Horizon ("Tetris") packing of UV charts (Lévy et al. 2002, §5): the atlas keeps, per texel
// column, the height of what has been placed; each chart, described by its lowest and highest
// texel per column (grown by the gutter), drops in at the column offset and quarter-turn where it
// ends lowest. Charts interlock along their real outlines instead of their bounding rectangles.
// Also the skyline packer of rectangles that gives the first, surely fitting density, and a convex
// hull.
#include <math.h>
#include <stdlib.h>
#include <string.h>
#include "export/uv_internal.h"

// NaN-free min/max without libm calls (the inputs here are finite or ±INFINITY)
#define MIN2(a, b) ((a) < (b) ? (a) : (b))
#define MAX2(a, b) ((a) > (b) ? (a) : (b))

// The chart's triangles in texel units after rotation `rot`: point (a, b) → rotated.
static void rot_pt(int rot, double W, double H, double a, double b, double* x, double* y) {
    switch (rot & 3) {
        case 0: *x = a; *y = b; break;
        case 1: *x = H - b; *y = a; break;
        case 2: *x = W - a; *y = H - b; break;
        default: *x = b; *y = W - a; break;
    }
}

// lo/hi [nc]: the lowest/highest y of the chart within each column [j, j+1) (±INFINITY when empty).
static void column_extents(const mlb_uv_pack_chart* c, double s, int rot, int nc, double* lo, double* hi) {
    double W = c->w * s, H = c->h * s;
    for (int j = 0; j < nc; j++) { lo[j] = INFINITY; hi[j] = -INFINITY; }
    for (int t = 0; t < c->n_tri; t++) {
        double P[3][2];
        for (int i = 0; i < 3; i++) rot_pt(rot, W, H, c->tri[6 * t + 2 * i] * s, c->tri[6 * t + 2 * i + 1] * s, &P[i][0], &P[i][1]);
        double xmin = MIN2(P[0][0], MIN2(P[1][0], P[2][0])), xmax = MAX2(P[0][0], MAX2(P[1][0], P[2][0]));
        int j0 = (int)floor(xmin), j1 = (int)floor(xmax);
        if (j0 < 0) j0 = 0;
        if (j1 > nc - 1) j1 = nc - 1;
        for (int j = j0; j <= j1; j++) {
            double a = j, b = j + 1.0, l = INFINITY, h = -INFINITY;
            for (int i = 0; i < 3; i++) {
                const double *p = P[i], *q = P[(i + 1) % 3];
                if (p[0] >= a && p[0] <= b) { l = MIN2(l, p[1]); h = MAX2(h, p[1]); }
                double dx = q[0] - p[0];
                if (dx != 0)
                    for (int e = 0; e < 2; e++) {
                        double xe = e ? b : a, u = (xe - p[0]) / dx;
                        if (u >= 0 && u <= 1) {
                            double y = p[1] + u * (q[1] - p[1]);
                            l = MIN2(l, y);
                            h = MAX2(h, y);
                        }
                    }
            }
            if (l <= h) { lo[j] = MIN2(lo[j], l); hi[j] = MAX2(hi[j], h); }
        }
    }
}

int mlb_uv_pack_horizon(const mlb_uv_pack_chart* c, const int* order, int n, double s, int gutter, int size,
                        mlb_uv_pack_place* out) {
    const int g = gutter;
    double* horizon = calloc((size_t)size, sizeof *horizon);   // [size] height per atlas column
    int cap = 0;
    double *lo = NULL, *hi = NULL, *bot[4] = {0}, *top[4] = {0};
    int ok = 1;
    if (!horizon) return -1;
    for (int k = 0; k < n && ok == 1; k++) {
        const mlb_uv_pack_chart* ch = &c[order[k]];
        double W = ch->w * s, H = ch->h * s;
        if (!(W + 2 * g <= size && H + 2 * g <= size)) { ok = 0; break; }   // no room at this density (and no huge profiles)
        int ncr[4], nr[4];
        ncr[0] = ncr[2] = (int)ceil(W) > 0 ? (int)ceil(W) : 1;
        ncr[1] = ncr[3] = (int)ceil(H) > 0 ? (int)ceil(H) : 1;
        int need = (ncr[0] > ncr[1] ? ncr[0] : ncr[1]) + 2 * g + 1;
        if (need > cap) {
            cap = need;
            double* p = realloc(lo, sizeof *p * 2 * (size_t)cap);
            if (!p) { ok = -1; break; }
            lo = p;
            hi = p + cap;
            for (int r = 0; r < 4; r++) {
                free(bot[r]);
                bot[r] = malloc(sizeof *bot[r] * 2 * (size_t)cap);
                if (!bot[r]) { ok = -1; break; }
                top[r] = bot[r] + cap;
            }
            if (ok != 1) break;
        }
        double best = INFINITY, best_y = 0;
        int best_x = -1, best_r = 0;
        for (int r = 0; r < 4; r++) {
            int nc = ncr[r], m = nc + 2 * g;
            nr[r] = m;
            column_extents(ch, s, r, nc, lo, hi);
            // grow by the gutter: column k of the profile is atlas column X + k, chart column k − g
            double maxtop = -INFINITY;
            for (int kk = 0; kk < m; kk++) {
                double b = INFINITY, t = -INFINITY;
                for (int j = kk - 2 * g; j <= kk; j++)
                    if (j >= 0 && j < nc) { b = MIN2(b, lo[j]); t = MAX2(t, hi[j]); }
                bot[r][kk] = b - g;
                top[r][kk] = t + g;
                if (t > -INFINITY) maxtop = MAX2(maxtop, t + g);
            }
            if (m > size) continue;
            for (int X = 0; X + m <= size; X++) {
                double Y = 0;
                int pruned = 0;
                for (int kk = 0; kk < m; kk++) {
                    if (bot[r][kk] == INFINITY) continue;
                    double y = horizon[X + kk] - bot[r][kk];
                    if (y > Y) {
                        Y = y;
                        if (Y + maxtop >= best) { pruned = 1; break; }
                    }
                }
                if (pruned) continue;
                if (Y + maxtop < best) { best = Y + maxtop; best_y = Y; best_x = X; best_r = r; }
            }
        }
        if (best_x < 0 || best > size) { ok = 0; break; }
        for (int kk = 0; kk < nr[best_r]; kk++)
            if (top[best_r][kk] > -INFINITY) horizon[best_x + kk] = MAX2(horizon[best_x + kk], best_y + top[best_r][kk]);
        if (out) {
            out[order[k]].x = best_x + g;
            out[order[k]].y = best_y;
            out[order[k]].rot = best_r;
        }
    }
    free(horizon);
    free(lo);
    for (int r = 0; r < 4; r++) free(bot[r]);
    return ok;
}

// Skyline packing (bottom-left rule) of rectangles (w_i·s + 2g) × (h_i·s + 2g) in order `ord` into
// size × size; returns 1 when all fit (pos [n,2] lower-left corners, when not NULL). sky, tmp:
// scratch [2n + 4].

int mlb_uv_pack_skyline(const double* wh, const int* ord, int n, double s, double g, double size, double* pos,
                        mlb_uv_sky_seg* sky, mlb_uv_sky_seg* tmp) {
    int ns = 1;
    sky[0] = (mlb_uv_sky_seg){0, 0, size};
    for (int k = 0; k < n; k++) {
        double W = wh[2 * ord[k]] * s + 2 * g, H = wh[2 * ord[k] + 1] * s + 2 * g;
        double best_top = INFINITY, bx = 0, by = 0;
        for (int i = 0; i < ns; i++) {
            double x = sky[i].x;
            if (x + W > size) break;
            double y = 0;
            for (int j = i; j < ns && sky[j].x < x + W; j++) y = MAX2(y, sky[j].y);
            if (y + H <= size && y + H < best_top) { best_top = y + H; bx = x; by = y; }
        }
        if (best_top == INFINITY) return 0;
        if (pos) { pos[2 * ord[k]] = bx; pos[2 * ord[k] + 1] = by; }
        // new skyline: the parts left of bx, the rectangle's top, the parts right of bx + W
        int nt = 0;
        for (int i = 0; i < ns; i++) {
            double e = MIN2(sky[i].x + sky[i].w, bx);
            if (e > sky[i].x) tmp[nt++] = (mlb_uv_sky_seg){sky[i].x, sky[i].y, e - sky[i].x};
        }
        tmp[nt++] = (mlb_uv_sky_seg){bx, best_top, W};
        for (int i = 0; i < ns; i++) {
            double b0 = MAX2(sky[i].x, bx + W), e = sky[i].x + sky[i].w;
            if (e > b0) tmp[nt++] = (mlb_uv_sky_seg){b0, sky[i].y, e - b0};
        }
        ns = 0;   // merge neighbours at the same height
        for (int i = 0; i < nt; i++) {
            if (ns > 0 && sky[ns - 1].y == tmp[i].y) sky[ns - 1].w += tmp[i].w;
            else sky[ns++] = tmp[i];
        }
    }
    return 1;
}

// Convex hull (Andrew's monotone chain) of p [n,2], sorted in place; returns the hull size, hull
// [n + 1, 2] counter-clockwise.
static int pt_cmp(const void* a, const void* b) {
    const double *p = a, *q = b;
    if (p[0] != q[0]) return p[0] < q[0] ? -1 : 1;
    return (p[1] > q[1]) - (p[1] < q[1]);
}
int mlb_uv_convex_hull(double* p, int n, double* hull) {
    qsort(p, (size_t)n, 2 * sizeof(double), pt_cmp);
    if (n < 3) { memcpy(hull, p, sizeof(double) * 2 * (size_t)n); return n; }
    int k = 0;
    for (int pass = 0; pass < 2; pass++) {
        int start = k;
        for (int i = 0; i < n; i++) {
            const double* q = pass == 0 ? p + 2 * i : p + 2 * (n - 1 - i);
            while (k >= start + 2) {
                const double *a = hull + 2 * (k - 2), *b = hull + 2 * (k - 1);
                if ((b[0] - a[0]) * (q[1] - a[1]) - (b[1] - a[1]) * (q[0] - a[0]) <= 0) k--;
                else break;
            }
            hull[2 * k] = q[0];
            hull[2 * k + 1] = q[1];
            k++;
        }
        k--;   // the last point is the first of the other chain
    }
    return k;
}

